"""The evaluation's draws and texture bytes per frame (hlod_core/report/draw_cost.py), checked against
counts made here another way, node by node, on a baked corner of the statue square: four statues, a
bush and the ground, each its own image-textured material."""
import json
import sys

import numpy as np
import pytest
from PIL import Image

from helpers import ROOT
from hlod_core.io.hlod_file import load as load_hlod
from hlod_core.io.textures import load_images
from hlod_core.model.camera_path import load_path
from hlod_core.render.renderer import Renderer
from hlod_core.report import evaluate, per_frame_file
from hlod_core.report.draw_cost import DrawCost
from hlod_core.traversal.methods import make
from processes import hlod, last_json

sys.path.insert(0, str(ROOT / "tests" / "scenes"))
import statue_square  # tests/scenes/statue_square.py, found through the path set above

SIZE = (160, 120)


@pytest.fixture(scope="module")
def corner(tmp_path_factory):
    """(hlod file, path file): statues in cells 0-3, the bush of cell 7 and the ground, baked at 1,000
    triangles a node keeping the sources' materials; the far-to-near path cut to 24 frames."""
    spec = statue_square.scene("small")
    entries = json.loads(spec.read_text())["models"]
    cells = ("00", "01", "02", "03", "07")
    keep = [e for e in entries if e["path"] == "ground.obj" or e["path"].split(".")[0].split("_")[1] in cells]
    assert len(keep) == 6
    folder = tmp_path_factory.mktemp("corner")
    for e in keep:
        e["path"] = str(spec.parent / e["path"])
    (folder / "corner.json").write_text(json.dumps({"models": keep}))
    out = folder / "corner.hlod"
    # the sources' materials on every level, so inner nodes draw in several parts
    summary = last_json(hlod("-q", "bake", folder / "corner.json", "-o", out, "--target-tris", "1000", "--no-cache",
                             "--keep-materials"))
    assert summary["nodes"] > 10
    path = json.loads(statue_square.far_path("small").read_text())
    path["frames"] = path["frames"][::4][:24]
    path.pop("parts")
    (folder / "path.json").write_text(json.dumps(path))
    return out, folder / "path.json"


def by_node(hlod_, drawn) -> tuple[int, float]:
    """(draws, texture bytes) of the nodes `drawn`, node by node: a draw per run of one material in a
    node's triangles; each distinct texture file once, as 4/3 x w x h x 4 bytes (its size read here)."""
    draws, files = 0, set()
    for node in drawn:
        lo = int(hlod_.tri_offset[node])
        materials = hlod_.tri_material[lo:lo + int(hlod_.tri_count[node])].tolist()
        draws += 1 + sum(a != b for a, b in zip(materials, materials[1:]))
        files |= {hlod_.materials[m].texture for m in materials if hlod_.materials[m].texture}
    sizes = [Image.open(f).size for f in files]
    return draws, sum(4 / 3 * w * h * 4 for w, h in sizes)


@pytest.mark.gl
def test_draw_cost_of_traversed_frames_matches_a_count_node_by_node(corner, gl_ctx):
    """Coh(P) and Full along the path: every frame's figures equal the count node by node, and the
    frames include ones that draw inner nodes of several materials (draws above drawn nodes)."""
    hlod_ = load_hlod(corner[0])
    path = load_path(corner[1])
    images = load_images(hlod_)
    assert len(images) == len(hlod_.materials) == 6
    cost = DrawCost(hlod_, images)
    renderer = Renderer(gl_ctx, hlod_, size=SIZE, images=images)
    inner_frames = more_draws = 0
    try:
        for method in ("coh", "full"):
            traversal = make(method, hlod_, renderer)
            for i in range(len(path)):
                stats = traversal.frame(path.view(i, SIZE))
                assert cost.frame(stats.drawn) == pytest.approx(by_node(hlod_, stats.drawn)), (method, i)
                inner_frames += bool((~hlod_.is_leaf[stats.drawn]).any())
                more_draws += cost.frame(stats.drawn)[0] > stats.dn
    finally:
        renderer.release()
    assert inner_frames > 0 and more_draws > 0
    assert cost.frame([]) == (0, 0.0)


@pytest.mark.gl
def test_evaluate_reports_draws_and_texture_bytes(corner, tmp_path):
    """evaluate's report.json, per_frame.npz, report.md and last line carry the columns: Full's
    figures on the far frames (every leaf in view) are the count over every leaf; each method's mean
    is the mean of its per-frame figures."""
    out = tmp_path / "report"
    line = last_json(hlod("-q", "evaluate", corner[0], "--out", out, "--path", corner[1], "--size", "160x120",
                          "--methods", "full", "coh_p", "--repeat", "1", "--psnr-frames", "3"))
    hlod_ = load_hlod(corner[0])
    report = json.loads((out / "report.json").read_text())
    costs = per_frame_file.load_costs(out / "per_frame.npz")
    leaves = np.flatnonzero(hlod_.is_leaf)
    draws, texture = by_node(hlod_, leaves)
    assert costs["full"]["draws"][0] == draws and costs["full"]["texture_bytes"][0] == pytest.approx(texture)
    for key, row in report["methods"].items():
        assert line["methods"][key]["draws"] == row["draws"] == pytest.approx(np.mean(costs[key]["draws"]))
        assert row["texture_bytes"] == pytest.approx(np.mean(costs[key]["texture_bytes"]))
        assert row["draws_max"] == np.max(costs[key]["draws"]) and row["draws"] >= row["dn"]
    assert report["methods"]["coh_p"]["draws"] < report["methods"]["full"]["draws"]
    md = (out / "report.md").read_text()
    full = report["methods"]["full"]
    assert (f"| Full | {full['tris']:,.0f} | {full['frame_ms']:,.2f} | {full['draws']:,.1f} | "
            f"{full['draws_max']:,.0f} | {full['texture_bytes'] / 2**20:,.2f} |") in md
    assert evaluate.LABELS["coh_p"] in md.split("## Draws and texture memory per frame")[1]


def test_statue_square_is_what_its_docstring_says():
    """The small statue square as the bake reads it: 37 materials, each with its own texture file;
    the 4 bushes alpha-masked; one statue's UVs far outside [0, 1]; the ground's repeating; the
    triangles its facts.json gives."""
    from hlod_core.io import meshes

    spec = statue_square.scene("small")
    facts = json.loads((spec.parent / "facts.json").read_text())
    mesh = meshes.load_inputs([spec])
    assert mesh.tri_count == facts["triangles"] and len(mesh.materials) == facts["materials"] == 37
    assert len({m.texture for m in mesh.materials if m.texture}) == 37
    assert sorted(m.name for m in mesh.materials if m.alpha_mode == "MASK") == [f"bush_{k:02d}" for k in
                                                                                statue_square.BUSH_CELLS]
    names = [m.name for m in mesh.materials]
    corner_uvs = mesh.uvs[mesh.faces]  # (f, 3, 2)
    far = corner_uvs[mesh.material_ids == names.index(f"statue_{statue_square.FAR_UV_CELL:02d}_teapot")]
    assert far[..., 0].min() >= 999.0 and far[..., 1].max() <= -496.0
    ground = corner_uvs[mesh.material_ids == names.index("ground")]
    assert np.ptp(ground[..., 0]) > 9.0 and np.ptp(ground[..., 1]) > 9.0
