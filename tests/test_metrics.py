"""docs/how-it-works.md#the-runtime metrics and the cases of docs/how-it-works.md#numerical-stability, on exact small
inputs (no GL)."""
import warnings

import numpy as np
import pytest

from hlod_core.core import colour
from hlod_core.model.view import View, look_at, orthographic, perspective
from hlod_core.traversal import alpha_estimators, boxes, metrics
from silhouette_reference import silhouette_pixels

MU = np.linspace(0.0, 1.0, 2001)
KS = [1.0, 10.0, 1e3, 1e6, 1e9, np.inf]
PAPER_ST = [(0.6, 0.2), (0.7, 0.15), (0.9, 0.05)]


@pytest.fixture(autouse=True)
def no_numpy_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(all="raise"):
            yield


def _view(*, eye=(0, 0, 10), target=(0, 0, 0), size=(640, 480), fovy=60.0, near=0.01, far=1000.0, ortho=None):
    w, h = size
    proj = orthographic(ortho, w / h, near=near, far=far) if ortho else perspective(fovy, w / h, near=near, far=far)
    return View(eye=np.array(eye, float), view=look_at(eye, target, (0, 1, 0)), projection=proj, width=w, height=h)


# --- P_{s,t} -----------------------------------------------------------------------------------

@pytest.mark.parametrize("k", KS)
@pytest.mark.parametrize("s, t", PAPER_ST + [(0.5, 0.0), (0.5, 1.0), (1.0, 0.3), (0.0, 0.4), (1.0, 0.0), (1.0, 1.0)])
def test_bias_endpoints_monotone_and_finite(s, t, k):
    p = metrics.bias(MU, s, t, k=k)
    assert p[0] == 0.0 and p[-1] == 1.0  # exactly, for every s, t, k
    assert np.all(np.isfinite(p)) and np.all((p >= 0) & (p <= 1))
    assert np.all(np.diff(p) >= 0)


@pytest.mark.parametrize("k", KS)
def test_s_zero_is_mu(k):
    assert np.array_equal(metrics.bias(MU, 0.0, 0.3, k=k), MU)


@pytest.mark.parametrize("s, t", PAPER_ST + [(1.0, 0.5), (0.5, 0.99)])
@pytest.mark.parametrize("k", [1e2, 1e3, 1e6, 1e9, np.inf])
def test_aggressive_below_t_conservative_above(s, t, k):
    p = metrics.bias(MU, s, t, k=k)
    band = metrics.band_half_width(k)
    below, above = MU < t - band, MU >= t + band
    assert np.all(p[below] <= MU[below] + 1e-15)
    assert np.all(p[above] >= MU[above] - 1e-15)


@pytest.mark.parametrize("s, t", PAPER_ST + [(0.0, 0.5), (1.0, 0.0), (1.0, 1.0)])
@pytest.mark.parametrize("k", KS + [1e-9])
def test_scalar_bias_equals_the_array_bias(s, t, k):
    """The traversal's per-node plain-Python P_{s,t} gives the array version's values."""
    grid = np.concatenate([MU, [t, max(t - 1e-12, 0.0), min(t + 1e-12, 1.0)]])
    p = metrics.bias_function(s, t, k=k)
    scalar = np.array([p(float(mu)) for mu in grid])
    assert np.allclose(scalar, metrics.bias(grid, s, t, k=k), rtol=0, atol=1e-12)
    assert p(float("nan")) == 0.0


def test_step_is_the_default_and_exact():
    # step at t = 0.05 with s = 0.9: below t, P = 0.1 mu; from t on, P = 0.1 mu + 0.9
    assert metrics.bias(0.04, 0.9, 0.05) == pytest.approx(0.004)
    assert metrics.bias(0.05, 0.9, 0.05) == pytest.approx(0.905)
    assert metrics.band_half_width(np.inf) == 0.0


def test_t_zero_and_t_one():
    # t = 0: everything above 0 is conservative (S = 1); t = 1: only mu = 1 is
    assert np.all(metrics.bias(MU[1:], 1.0, 0.0) == 1.0)
    assert np.all(metrics.bias(MU[:-1], 1.0, 1.0) == 0.0)


def test_huge_k_matches_the_step_away_from_t():
    away = np.abs(MU - 0.2) > 1e-6
    assert np.allclose(metrics.bias(MU, 0.6, 0.2, k=1e9)[away], metrics.bias(MU, 0.6, 0.2)[away])


def test_bad_bias_parameters_are_rejected():
    for s, t, k in [(-0.1, 0.5, 1.0), (0.5, 1.5, 1.0), (0.5, 0.5, 0.0), (0.5, 0.5, np.nan)]:
        with pytest.raises(ValueError):
            metrics.bias(0.5, s, t, k=k)


def test_modulation_colours_blue_magenta_red():
    c = colour.modulation_colour(np.array([0.0, 0.5, 1.0]))
    assert c[0].argmax() == 2 and c[2].argmax() == 0  # blue, red
    assert c[1][0] > 0.5 and c[1][2] > 0.5 and c[1][1] < 0.3  # magenta


# --- SSE --------------------------------------------------------------------------------------

def test_sse_perspective_exact():
    v = _view(size=(640, 480), fovy=90.0)  # P11 = 1/tan(45 deg) = 1
    centre, radius = np.array([[0.0, 0.0, 0.0]]), np.array([2.0])
    # d = 10 - 2 = 8; SSE = 0.5 * (480/2) * 1 / 8 = 15 px
    out = metrics.sse(v, np.array([0.5]), center=centre, radius=radius, is_leaf=np.array([False]))
    assert out[0] == pytest.approx(15.0)


def test_sse_orthographic_exact_and_distance_free():
    v = _view(ortho=20.0)  # P11 = 2/20; SSE = MSE * 240 * 0.1
    out = metrics.sse(v, np.array([0.5, 0.5]), center=np.array([[0, 0, 0], [0, 0, -500.0]]),
                      radius=np.array([1.0, 1.0]), is_leaf=np.array([False, False]))
    assert out.tolist() == pytest.approx([12.0, 12.0])


def test_eye_inside_sphere_refines_and_leaves_are_zero_not_nan():
    v = _view(eye=(0, 0, 0.5))
    out = metrics.sse(v, np.array([1.0, 1.0, 0.0]), center=np.zeros((3, 3)), radius=np.array([1.0, 1.0, 1.0]),
                      is_leaf=np.array([False, True, True]))
    assert out[0] == np.inf and out[1] == 0.0 and out[2] == 0.0


def test_eye_on_sphere_surface_refines():
    v = _view(eye=(0, 0, 1.0))
    out = metrics.sse(v, np.array([1e-9]), center=np.zeros((1, 3)), radius=np.array([1.0]),
                      is_leaf=np.array([False]))
    assert out[0] == np.inf


@pytest.mark.parametrize("size", [(1, 1), (7680, 4320)])
def test_extreme_viewports_give_finite_sse(size):
    v = _view(size=size)
    out = metrics.sse(v, np.array([1e-4, 1e5]), center=np.array([[0, 0, 0], [0, 0, -1e5]]),
                      radius=np.array([1e-4, 1.0]), is_leaf=np.array([False, False]))
    assert np.all(np.isfinite(out)) and np.all(out > 0)


def test_scene_at_1e6_and_extreme_near_far():
    c = np.array([[1e6, 1e6, 1e6]])
    v = _view(eye=(1e6, 1e6, 1e6 + 5), target=(1e6, 1e6, 1e6), near=1e-4, far=1e5)
    out = metrics.sse(v, np.array([0.01]), center=c, radius=np.array([1.0]), is_leaf=np.array([False]))
    # d = 4; SSE = 0.01 * 240 * P11 / 4 with P11 = 1/tan(30 deg)
    assert out[0] == pytest.approx(0.01 * 240 * (1 / np.tan(np.radians(30))) / 4, rel=1e-9)
    assert np.all(boxes.boxes_in_frustum(v, c - 1, c + 1))


def test_nodes_at_1e_minus_4_and_1e5_units():
    v = _view(eye=(0, 0, 1e-3), near=1e-4, far=1e6)
    out = metrics.sse(v, np.array([1e-6, 1e3]), center=np.array([[0, 0, 0], [0, 0, -1e5]]),
                      radius=np.array([1e-4, 1e4]), is_leaf=np.array([False, False]))
    assert np.all(np.isfinite(out)) and np.all(out > 0)


# --- frustum and distances ---------------------------------------------------------------------

def test_frustum_keeps_boxes_in_view_and_drops_boxes_behind():
    v = _view()
    lo = np.array([[-1, -1, -1], [-1, -1, 20], [50, 50, -1]], float)
    assert boxes.boxes_in_frustum(v, lo, lo + 2).tolist() == [True, False, False]


def test_boxes_reaching_in_front_of_the_near_plane():
    v = _view(eye=(0, 0, 10), near=2.0)  # near plane at z = 8
    lo = np.array([[-1, -1, 7.0], [-1, -1, 8.5], [-1, -1, 0.0]])
    hi = np.array([[1, 1, 7.5], [1, 1, 9.0], [1, 1, 1.0]])
    assert boxes.boxes_cross_near_plane(v, lo, hi).tolist() == [False, True, False]


def test_box_distance_is_zero_inside_and_on_faces():
    lo, hi = np.array([[0, 0, 0.0]]), np.array([[1, 1, 1.0]])
    assert boxes.box_distance(np.array([0.5, 0.5, 0.5]), lo, hi)[0] == 0.0
    assert boxes.box_distance(np.array([1.0, 0.5, 0.5]), lo, hi)[0] == 0.0  # eye on a face
    assert boxes.box_distance(np.array([4.0, 5.0, 0.5]), lo, hi)[0] == pytest.approx(5.0)


@pytest.mark.parametrize("product_boxes", [None, 64])
def test_view_tests_equal_the_textbook_box_tests(product_boxes, monkeypatch):
    """The traversal's one pass over the node table (boxes.view_tests on BoxRows) gives what the
    textbook tests give box by box: in the frustum unless all 8 corners lie outside one plane
    (exact for these boxes: none is near a plane's edge), the distance from the eye to the box's
    nearest point, and unqueryable where the padded box holds the eye or a corner lies behind the
    near plane; and the distance from the eye to each given centre (the SSE's spheres). Random
    boxes around and across the eye, perspective (three near planes) and orthographic views; the
    distances bit for bit (same operations), the booleans exactly. product_boxes 64: the frustum
    test's matrix product in chunks of 64 boxes (as above 4,096 boxes)."""
    if product_boxes is not None:
        monkeypatch.setattr(boxes, "PRODUCT_BOXES", product_boxes)
    rng = np.random.default_rng(7)
    checked = {"in": 0, "out": 0, "unqueryable": 0, "eye inside": 0}
    for trial in range(40):
        eye = rng.normal(size=3) * 5
        ortho = 8.0 if trial % 5 == 0 else None
        v = _view(eye=eye, target=rng.normal(size=3), size=(320, 240), fovy=rng.uniform(20, 100), ortho=ortho,
                  near=float(rng.choice([0.01, 0.5, 2.0])), far=60.0)
        centre, half = rng.normal(size=(200, 3)) * 6, rng.uniform(0.01, 3, size=(200, 3))
        centre[:10] = eye + rng.normal(size=(10, 3)) * 0.2  # boxes around or beside the eye
        lo, hi, pad = centre - half, centre + half, 0.05
        spheres = centre + rng.normal(size=centre.shape) * 10.0 ** rng.uniform(-3, 3, size=(200, 1))
        tests = boxes.view_tests(v, boxes.BoxRows.of(lo, hi, query_pad=pad, centre=spheres))
        in_frustum, distance, unqueryable = tests.in_frustum, tests.distance, tests.unqueryable
        assert np.array_equal(tests.centre_distance, np.linalg.norm(spheres - v.eye, axis=1))
        planes = boxes.frustum_planes(v)
        corners = boxes.box_corners(lo[:, None, :], hi[:, None, :])  # (n,8,3)
        outside_one_plane = np.any(np.all(corners @ planes[:, :3].T + planes[:, 3] < 0, axis=1), axis=1)
        assert np.array_equal(in_frustum, ~outside_one_plane)
        nearest = np.clip(v.eye, lo, hi)
        assert np.array_equal(distance, np.linalg.norm(nearest - v.eye, axis=1))
        padded = boxes.box_corners((lo - pad)[:, None, :], (hi + pad)[:, None, :])
        eye_inside = np.all((lo - pad <= v.eye) & (v.eye <= hi + pad), axis=1)
        behind_near = np.any(padded @ planes[4, :3] + planes[4, 3] < 0, axis=1)
        assert np.array_equal(unqueryable, eye_inside | behind_near)
        assert np.array_equal(tests.behind_near, behind_near)
        checked["in"] += int(in_frustum.sum())
        checked["out"] += int((~in_frustum).sum())
        checked["unqueryable"] += int(unqueryable.sum())
        checked["eye inside"] += int(eye_inside.sum())
    assert min(checked.values()) > 20, checked  # every outcome occurs


@pytest.mark.parametrize("order", ["C", "F"])
def test_sphere_distance_is_the_norm_bit_for_bit(order):
    """sphere_distance sums the axes' squares by columns, in np.linalg.norm's order: the same bits
    for a row-major or a column-major (the traversal's) centre array."""
    rng = np.random.default_rng(2)
    centre, radius = rng.normal(size=(500, 3)) * 10 ** rng.uniform(-3, 6, size=(500, 1)), rng.uniform(0, 5, 500)
    v = _view(eye=(3.0, -2.0, 7.0))
    got = metrics.sphere_distance(v, np.asarray(centre, order=order), radius)
    assert np.array_equal(got, np.linalg.norm(centre - v.eye, axis=1) - radius)


# --- alpha estimators (geometry only; compared with the query estimator in test_traversal_methods) ------

def test_projected_alpha_of_a_face_on_square():
    v = _view(eye=(0, 0, 10), fovy=90.0, size=(480, 480))  # 1 unit at distance d covers 240/d px
    # unit-depth box whose front face (z = 1) is 2 x 2 at distance 9: 2 * 240 / 9 px on a side
    area = alpha_estimators.alpha_projected(v, np.array([-1, -1, 0.0]), np.array([1, 1, 1.0]))
    back = (2 * 240 / 10) ** 2  # the back face projects smaller and lies inside the front face
    assert area == pytest.approx((2 * 240 / 9) ** 2, rel=1e-9) and area > back


def test_projected_alpha_clips_to_the_viewport_and_handles_the_near_plane():
    v = _view(eye=(0, 0, 0.5), size=(64, 48))  # eye inside the box: covers the whole viewport
    inside = alpha_estimators.alpha_projected(v, np.array([-1, -1, -1.0]), np.array([1, 1, 1.0]))
    assert inside == pytest.approx(64 * 48)
    behind = alpha_estimators.alpha_projected(v, np.array([-1, -1, 5.0]), np.array([1, 1, 6.0]))
    assert behind == 0.0


def test_projected_alpha_vectorised_equals_the_hull_of_each_box():
    """The back-face sum over all boxes at once equals the one-box hull reference (corners and
    near-plane crossings, convex hull, viewport clip) on boxes in front, across, behind and around
    the eye, in perspective (three near planes) and orthographic views."""
    rng = np.random.default_rng(3)
    compared = covered = 0
    for trial in range(60):
        eye = rng.normal(size=3) * 5
        if trial % 5 == 0:
            v = _view(eye=eye, target=rng.normal(size=3), size=(320, 240), ortho=8.0, near=0.1, far=100.0)
        else:
            v = _view(eye=eye, target=rng.normal(size=3), size=(320, 240), fovy=rng.uniform(20, 100),
                      near=float(rng.choice([0.01, 0.5, 2.0])), far=100.0)
        centre, half = rng.normal(size=(40, 3)) * 4, rng.uniform(0.01, 3, size=(40, 3))
        centre[0] = eye  # one box around the eye
        lo, hi = centre - half, centre + half
        many = alpha_estimators.alpha_projected(v, lo, hi)
        one_by_one = np.array([silhouette_pixels(v, lo[i], hi[i]) for i in range(len(lo))])
        np.testing.assert_allclose(many, one_by_one, rtol=1e-9, atol=1e-6)
        compared += len(lo)
        covered += int(np.count_nonzero(one_by_one > 0))
    assert covered > compared // 4  # not a comparison of zeros


def test_cube_alpha_formula_and_eye_at_centre():
    v = _view(eye=(0, 0, 10), fovy=90.0, size=(480, 480))
    lo, hi = np.array([[-1, -1, -1.0]]), np.array([[1, 1, 1.0]])
    # side 2 at d = 10: (2 * 240 / 10)^2
    cube = alpha_estimators.alpha_cube(v, np.array([2.0]), box_min=lo, box_max=hi)
    assert cube[0] == pytest.approx((2 * 240 / 10) ** 2)
    at_centre = _view(eye=(0, 0, 0), target=(0, 0, -1), fovy=90.0)
    assert alpha_estimators.alpha_cube(at_centre, np.array([2.0]), box_min=lo, box_max=hi)[0] == np.inf


# --- frustum planes over far/near ratios from 1e4 to 1e20 ---------------------------

def test_frustum_planes_exact_for_a_90_degree_camera_at_the_origin():
    # looking down -z, fovy 90, square viewport: inside is |x| <= -z, |y| <= -z, 1 <= -z <= 100
    v = _view(eye=(0, 0, 0), target=(0, 0, -1), fovy=90.0, size=(300, 300), near=1.0, far=100.0)
    r = 1 / np.sqrt(2)
    expected = [[r, 0, -r, 0], [-r, 0, -r, 0], [0, r, -r, 0], [0, -r, -r, 0], [0, 0, -1, -1], [0, 0, 1, 100]]
    assert np.allclose(boxes.frustum_planes(v), expected, rtol=0, atol=1e-12)
    # far/near 1e20: P[2][2] rounds to -1, the far plane lies at infinity and keeps everything
    huge = _view(eye=(0, 0, 0), target=(0, 0, -1), fovy=90.0, size=(300, 300), near=1.0, far=1e20)
    assert np.array_equal(boxes.frustum_planes(huge)[5], [0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize("far_over_near", [1e4, 1e8, 1e12, 1e16, 1e17, 1e20])
@pytest.mark.parametrize("ortho", [None, 4.0])
def test_frustum_holds_for_far_over_near_up_to_1e20(far_over_near, ortho):
    """A camera away from the origin looking along an oblique axis: boxes along the view axis from
    just past the near plane to half the far distance are in; behind the eye, far to the side and
    beyond the far plane are out. The old planes (rows of P @ V) gave the far plane a zero normal
    from far/near ~1e16 on and culled everything (0/0). A perspective far plane beyond about 1e16
    near distances cannot be told from infinity in the matrix; there it culls nothing in front."""
    near = 0.01
    far = near * far_over_near
    eye = np.array([1e3, -2e3, 50.0])
    v = _view(eye=eye, target=eye + [1.0, 2.0, -0.5], near=near, far=far, ortho=ortho)
    axis, side = -v.view[2, :3], v.view[0, :3]  # the camera's own axes (rows of the rotation)
    distance = np.array([2 * near, 1.0, 0.5 * far, -1.0, 10.0, 2.0 * far])
    lateral = np.array([0.0, 0.0, 0.0, 0.0, 1e3, 0.0])
    centre = eye + distance[:, None] * axis + lateral[:, None] * side
    half = (0.01 * near + 1e-14 * np.abs(distance))[:, None]  # at least the rounding of the centre
    inside = boxes.boxes_in_frustum(v, centre - half, centre + half)
    # the matrix tells a perspective far plane from infinity while P[2][2] has not rounded to -1
    far_at_infinity = ortho is None and v.projection[2, 2] == -1.0
    assert far_at_infinity == (ortho is None and far_over_near >= 1e17)
    assert inside.tolist() == [True, True, True, False, False, far_at_infinity]
    planes = boxes.frustum_planes(v)
    assert np.all(np.isfinite(planes)) and np.allclose(np.linalg.norm(planes[:, :3], axis=1)[:5], 1.0)
