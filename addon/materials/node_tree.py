"""A material's base colour read from its node tree, as the viewport's Material Preview draws it.

The surface shaders are found from the active output (through Mix/Add Shader nodes): one Principled
BSDF (beside Transparent, Holdout or Emission shaders) gives its Base Color and Alpha, an Emission
or Background shader alone (an unlit material, as the glTF importer builds for
KHR_materials_unlit) its Color. Any other surface (a Diffuse, Toon or Glossy BSDF, a node group
such as the Diffuse and Glossy groups glTF exporters shipped before the Principled BSDF existed,
two Principled BSDFs mixed, Emission mixed with a Diffuse BSDF) has no Base Color to read: it is
`unreadable` with `whole_surface` set, and Cycles bakes its diffuse albedo (cycles_bake). From the
colour socket the tree is followed
upstream and turned into a function of the one varying source it holds: an image (an Image
Texture node, with the UV map and the constant Mapping before it) or a colour attribute (Color
Attribute or Attribute node). Colour nodes on the way (Mix / Mix RGB and their blend modes,
Hue/Saturation/Value, Gamma, Brightness/Contrast, Invert, RGB Curves, RGB and Value nodes, reroutes,
node groups such as the glTF importer's) become numpy functions (colour_formulas), so any mix of
them is evaluated on all the image's pixels (or the attribute's values) at once.

Data form: `BaseColour.function` maps the source's values (n,4) float32 linear RGBA to the base
colour (n,4) float32 linear RGBA (alpha: the surface's alpha); `uv_affine` (2,3) float64 maps a
UV (u, v, 1) to the image coordinate the texture is looked up at. A tree with two sources, or a
node this reader does not know (a procedural texture, a Math node) on the way, is `unreadable`
with the reason (Cycles bakes that socket's colour).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import mathutils
import numpy as np

from . import colour_formulas as cm

#: Samples of an RGB Curves node's table over [0, 1].
CURVE_TABLE_SIZE = 256
#: Shader nodes that are a surface by themselves (their Color is the colour drawn).
_EMISSIVE = {"EMISSION", "BACKGROUND"}
#: Shader nodes a surface passes through to find its BSDF.
_SHADER_MIXES = {"MIX_SHADER", "ADD_SHADER"}
#: Shader nodes beside one Principled BSDF that leave its Base Color the surface's colour (an alpha
#: mix, a glow added).
_PRINCIPLED_COMPANIONS = {"BSDF_TRANSPARENT", "HOLDOUT", "EMISSION"}

Function = Callable[[np.ndarray], np.ndarray]


class Unreadable(Exception):
    """The tree's base colour is not a function of one image or attribute; the message says why."""


@dataclass(frozen=True)
class Source:
    """The one varying input of a base colour: an image looked up through a UV map, or an attribute."""

    kind: str  # "image" or "attribute"
    image: object = None  # bpy.types.Image
    uv_map: str = ""  # "" = the mesh's active render UV map
    uv_affine: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))  # (2,3): (u, v, 1) -> image coordinate
    attribute: str = ""  # the colour attribute's name ("" = the active one)

    def key(self) -> tuple:
        return (self.kind, None if self.image is None else self.image.name_full, self.uv_map, self.uv_affine,
                self.attribute)


@dataclass(frozen=True)
class BaseColour:
    """What a material draws as its base colour (module notes). `constant` (4,) linear RGBA when
    no source; `identity`: the function returns the source's values unchanged (the colour of an
    image that can be used as it is)."""

    source: Source | None = None
    function: Function | None = None
    constant: tuple = (0.8, 0.8, 0.8, 1.0)
    identity: bool = False
    emissive: bool = False
    unreadable: str = ""
    whole_surface: bool = False  # unreadable: no Base Color to bake, Cycles bakes the surface's albedo


@dataclass
class _Value:
    """A socket's value: fn(source values (n,4)) -> (n,3) colour or (n,1) number; source None: constant."""

    fn: Function
    source: Source | None = None
    identity: bool = field(default=False)  # fn returns the source's colour as it is


def _constant(value) -> _Value:
    array = np.asarray(value, np.float32).reshape(1, -1)
    return _Value(lambda x, a=array: a)


def surface_nodes(material) -> list:
    """The shader nodes the active output's Surface draws, reached through Mix/Add Shader nodes and
    reroutes, in link order (a node group is one of them; its inside is not entered)."""
    tree = material.node_tree
    output = tree.get_output_node("ALL") if tree is not None else None
    found = []

    def visit(socket, depth=0):
        if depth > 16 or not socket.is_linked:
            return
        node = socket.links[0].from_node
        while node.type == "REROUTE" and node.inputs[0].is_linked:
            node = node.inputs[0].links[0].from_node
        if node.type in _SHADER_MIXES:
            for s in node.inputs:
                if s.type == "SHADER":
                    visit(s, depth + 1)
        elif node not in found:
            found.append(node)

    if output is not None:
        visit(output.inputs["Surface"])
    return found


def surface_shader(material):
    """(the node whose colour the material draws, True when it is emissive) or (None, False)."""
    found = surface_nodes(material)
    principled = next((n for n in found if n.type == "BSDF_PRINCIPLED"), None)
    if principled is not None:
        return principled, False
    emissive = next((n for n in found if n.type in _EMISSIVE), None)
    if emissive is not None and all(n.type in _EMISSIVE | {"BSDF_TRANSPARENT"} for n in found):
        return emissive, True
    tree = material.node_tree
    return next((n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"), None) if tree else None, False


def other_surface(material) -> str:
    """Why the material's surface has no one Base Color to read ("" when it has): the shaders it
    draws that are not one Principled BSDF with its companions, nor an emission alone (module notes)."""
    found = surface_nodes(material)
    principled = [n for n in found if n.type == "BSDF_PRINCIPLED"]
    if not found or all(n.type in _EMISSIVE | {"BSDF_TRANSPARENT"} for n in found):
        return ""
    others = [n for n in found if n.type not in _PRINCIPLED_COMPANIONS | {"BSDF_PRINCIPLED", "BACKGROUND"}]
    if len(principled) <= 1 and not others:
        return ""
    named = ", ".join(f"{n.name!r} ({n.bl_idname})" for n in (others or principled))
    return f"its surface is drawn by {named}, not one Principled BSDF"


def read_base_colour(material) -> BaseColour | None:
    """The material's base colour from its nodes (module notes); None when it has no surface node
    this reader takes (then the material's viewport colour stands)."""
    whole = other_surface(material)
    if whole:
        return BaseColour(unreadable=whole, whole_surface=True)
    node, emissive = surface_shader(material)
    if node is None:
        return None
    colour_socket = node.inputs["Color" if emissive else "Base Color"]
    alpha_socket = node.inputs.get("Alpha") if not emissive else None
    try:
        colour = _socket(colour_socket, ())
        alpha = _socket(alpha_socket, ()) if alpha_socket is not None else _constant([1.0])
        source = _one_source(colour, alpha)
    except Unreadable as exc:
        return BaseColour(emissive=emissive, unreadable=str(exc))
    if source is None:
        rgb, a = colour.fn(np.zeros((1, 4), np.float32)), alpha.fn(np.zeros((1, 4), np.float32))
        constant = (*np.broadcast_to(rgb, (1, 3))[0].tolist(), float(np.broadcast_to(a, (1, 1))[0, 0]))
        return BaseColour(constant=tuple(float(c) for c in constant), emissive=emissive)

    def function(x: np.ndarray, colour=colour, alpha=alpha) -> np.ndarray:
        n = x.shape[0]
        return np.concatenate([np.broadcast_to(colour.fn(x), (n, 3)), np.broadcast_to(alpha.fn(x), (n, 1))],
                              axis=1).astype(np.float32)

    identity = colour.identity and alpha.source is None and bool(np.all(alpha.fn(np.zeros((1, 4))) == 1.0))
    return BaseColour(source=source, function=function, identity=identity, emissive=emissive,
                      constant=(1.0, 1.0, 1.0, 1.0))


def _one_source(*values: _Value) -> Source | None:
    sources = {v.source.key(): v.source for v in values if v.source is not None}
    if len(sources) > 1:
        raise Unreadable(f"its base colour mixes {len(sources)} images or attributes")
    return next(iter(sources.values()), None)


# --- following the tree -------------------------------------------------------------------------

def _socket(socket, groups: tuple) -> _Value:
    """The value of an input socket (`groups`: the group nodes entered, innermost last)."""
    if not socket.is_linked or socket.links[0].is_muted:
        return _default(socket)
    link = socket.links[0]
    value = _output(link.from_node, link.from_socket, groups)
    return _convert(value, link.from_socket.type, socket.type)


def _default(socket) -> _Value:
    if not hasattr(socket, "default_value"):
        raise Unreadable(f"socket {socket.name!r} has no value")
    value = socket.default_value
    if socket.type == "RGBA":
        return _constant(list(value)[:3])
    if socket.type == "VALUE":
        return _constant([value])
    return _constant(list(value))


def _convert(value: _Value, from_type: str, to_type: str) -> _Value:
    """Blender's implicit conversions: colour -> number by luminance, number -> grey colour."""
    if from_type == to_type or to_type not in ("RGBA", "VALUE"):
        return value
    if to_type == "VALUE" and from_type in ("RGBA", "VECTOR"):
        fn = (lambda x, f=value.fn: cm.grey(f(x))) if from_type == "RGBA" else (
            lambda x, f=value.fn: np.mean(f(x), axis=1, keepdims=True))
        return _Value(fn, value.source)
    if to_type == "RGBA" and from_type == "VALUE":
        return _Value(lambda x, f=value.fn: np.repeat(f(x), 3, axis=1), value.source)
    return value


def _inputs(node, groups, *names: str) -> list[_Value]:
    return [_socket(_input(node, name), groups) for name in names]


def _input(node, name: str):
    """The input named (or identified) `name`; several sockets of one name: the enabled one."""
    matches = [s for s in node.inputs if s.identifier == name] or [s for s in node.inputs if s.name == name]
    enabled = [s for s in matches if s.enabled]
    if not (enabled or matches):
        raise Unreadable(f"node {node.name!r} has no input {name!r}")
    return (enabled or matches)[0]


def _combine(fn, *values: _Value) -> _Value:
    """A value computed from `values` by fn(*their arrays)."""
    source = _one_source(*values)
    return _Value(lambda x: fn(*(v.fn(x) for v in values)), source)


def _output(node, socket, groups: tuple) -> _Value:
    """The value of one output socket of `node`."""
    if node.mute:
        through = next((link.from_socket for link in node.internal_links if link.to_socket == socket), None)
        if through is None:
            raise Unreadable(f"muted node {node.name!r} passes nothing through")
        return _socket(through, groups)
    kind = node.type
    if kind == "REROUTE":
        return _socket(node.inputs[0], groups)
    if kind == "GROUP":
        return _group_output(node, socket, groups)
    if kind == "GROUP_INPUT":
        if not groups:
            raise Unreadable(f"group input {node.name!r} outside a group")
        outer = groups[-1]
        return _socket(next(s for s in outer.inputs if s.identifier == socket.identifier), groups[:-1])
    if kind in ("RGB", "VALUE"):
        return _constant(list(socket.default_value)[:3] if kind == "RGB" else [socket.default_value])
    if kind == "TEX_IMAGE":
        return _image(node, socket, groups)
    if kind in ("VERTEX_COLOR", "ATTRIBUTE"):
        return _attribute(node, socket)
    handler = _COLOUR_NODES.get(kind)
    if handler is None:
        raise Unreadable(f"node {node.name!r} ({node.bl_idname}) is not read")
    return handler(node, socket, groups)


def _group_output(node, socket, groups: tuple) -> _Value:
    tree = node.node_tree
    outputs = [n for n in tree.nodes if n.type == "GROUP_OUTPUT"] if tree is not None else []
    if not outputs:
        raise Unreadable(f"group {node.name!r} has no output")
    output = next((n for n in outputs if n.is_active_output), outputs[0])
    inner = next((s for s in output.inputs if s.identifier == socket.identifier), None)
    if inner is None:
        raise Unreadable(f"group {node.name!r} has no output {socket.name!r}")
    return _socket(inner, groups + (node,))


def _image(node, socket, groups) -> _Value:
    if node.image is None:
        return _constant([0.0, 0.0, 0.0] if socket.name == "Color" else [0.0])
    if node.projection != "FLAT":
        raise Unreadable(f"image node {node.name!r} uses {node.projection} projection")
    uv_map, affine = _coordinates(node.inputs["Vector"], groups)
    source = Source("image", image=node.image, uv_map=uv_map, uv_affine=tuple(map(tuple, affine.tolist())))
    if socket.name == "Alpha":
        return _Value(lambda x: x[:, 3:4], source)
    return _Value(lambda x: x[:, :3], source, identity=True)


def _attribute(node, socket) -> _Value:
    name = node.layer_name if node.type == "VERTEX_COLOR" else node.attribute_name
    if node.type == "ATTRIBUTE" and node.attribute_type != "GEOMETRY":
        raise Unreadable(f"attribute node {node.name!r} reads an {node.attribute_type.lower()} attribute")
    source = Source("attribute", attribute=name)
    if socket.name == "Alpha":
        return _Value(lambda x: x[:, 3:4], source)
    if socket.name == "Fac":
        return _Value(lambda x: cm.grey(x[:, :3]), source)
    return _Value(lambda x: x[:, :3], source, identity=True)


def _coordinates(socket, groups) -> tuple[str, np.ndarray]:
    """(UV map name, (2,3) affine) of an image's Vector input: a UV Map node or the Texture
    Coordinate's UV, through constant Mapping nodes (3D affine maps composed, then taken at z = 0)."""
    matrix, uv_map = np.eye(4), ""
    while socket.is_linked:
        link = socket.links[0]
        node = link.from_node
        if node.type == "REROUTE":
            socket = node.inputs[0]
        elif node.type == "MAPPING":
            matrix = matrix @ _mapping_matrix(node)
            socket = node.inputs["Vector"]
        elif node.type == "UVMAP":
            if node.from_instancer:
                raise Unreadable(f"UV map node {node.name!r} reads the instancer's UVs")
            uv_map = node.uv_map
            break
        elif node.type == "TEX_COORD" and link.from_socket.name == "UV":
            break
        else:
            raise Unreadable(f"an image's coordinates come from node {node.name!r} ({node.bl_idname})")
    return uv_map, matrix[:2][:, [0, 1, 3]]


def _mapping_matrix(node) -> np.ndarray:
    """The Mapping node's 4x4 map of a point (Cycles' svm_mapping): POINT T R S, TEXTURE its
    inverse, VECTOR R S; its inputs must be constants."""
    names = {"Location": None, "Rotation": None, "Scale": None}
    for name in names:
        socket = node.inputs.get(name)
        if socket is not None and socket.enabled and socket.is_linked:
            raise Unreadable(f"mapping node {node.name!r}: {name} is linked")
        names[name] = np.array(socket.default_value if socket is not None else (0, 0, 0), np.float64)
    rotation = np.array(mathutils.Euler(names["Rotation"].tolist(), "XYZ").to_matrix(), np.float64)
    scale = np.where(names["Scale"] != 0, names["Scale"], 1.0) if node.vector_type == "TEXTURE" else names["Scale"]
    m = np.eye(4)
    if node.vector_type in ("POINT", "VECTOR"):
        m[:3, :3] = rotation @ np.diag(scale)
        if node.vector_type == "POINT":
            m[:3, 3] = names["Location"]
    elif node.vector_type == "TEXTURE":
        m[:3, :3] = np.diag(1.0 / scale) @ rotation.T
        m[:3, 3] = -m[:3, :3] @ names["Location"]
    else:
        raise Unreadable(f"mapping node {node.name!r} maps normals")
    return m


# --- the colour nodes -----------------------------------------------------------------------------

def _mix(node, socket, groups) -> _Value:
    if node.type == "MIX":
        if node.data_type != "RGBA":
            raise Unreadable(f"mix node {node.name!r} mixes {node.data_type.lower()} values")
        t, a, b = _inputs(node, groups, "Factor_Float", "A_Color", "B_Color")
        clamp_factor, clamp_result = node.clamp_factor, node.clamp_result
    else:
        t, a, b = _inputs(node, groups, "Fac", "Color1", "Color2")
        clamp_factor, clamp_result = True, node.use_clamp
    mode = node.blend_type

    def fn(t, a, b):
        out = cm.blend(mode, np.clip(t, 0, 1) if clamp_factor else t, a, b)
        return np.clip(out, 0, 1) if clamp_result else out

    return _combine(fn, t, a, b)


def _hue_saturation(node, socket, groups) -> _Value:
    hue, sat, val, fac, colour = _inputs(node, groups, "Hue", "Saturation", "Value", "Fac", "Color")
    return _combine(lambda h, s, v, f, c: cm.hue_saturation_value(c, hue=h, saturation=s, value=v, factor=f),
                    hue, sat, val, fac, colour)


def _gamma(node, socket, groups) -> _Value:
    return _combine(cm.gamma, *_inputs(node, groups, "Color", "Gamma"))


def _bright_contrast(node, socket, groups) -> _Value:
    return _combine(lambda c, b, k: cm.brightness_contrast(c, bright=b, contrast=k),
                    *_inputs(node, groups, "Color", "Bright", "Contrast"))


def _invert(node, socket, groups) -> _Value:
    fac, colour = _inputs(node, groups, "Fac", "Color")
    return _combine(lambda f, c: cm.invert(c, f), fac, colour)


def _rgb_curves(node, socket, groups) -> _Value:
    mapping, tables = node.mapping, []

    def table() -> np.ndarray:  # made when the function is first evaluated, not when the tree is read
        if not tables:
            mapping.initialize()
            x = np.linspace(0.0, 1.0, CURVE_TABLE_SIZE)
            combined = [mapping.evaluate(mapping.curves[3], float(t)) for t in x]
            tables.append(np.array([[mapping.evaluate(mapping.curves[c], v) for v in combined] for c in range(3)],
                                   np.float32))
        return tables[0]

    fac, colour = _inputs(node, groups, "Fac", "Color")
    return _combine(lambda f, c: cm.curves(c, table(), f), fac, colour)


#: The Math node's operations on numbers (a, b, c) this reader evaluates.
_MATH = {"ADD": lambda a, b, c: a + b, "SUBTRACT": lambda a, b, c: a - b, "MULTIPLY": lambda a, b, c: a * b,
         "DIVIDE": lambda a, b, c: np.where(b != 0, a / np.where(b != 0, b, 1), 0),
         "MULTIPLY_ADD": lambda a, b, c: a * b + c, "POWER": lambda a, b, c: np.power(np.maximum(a, 0), b),
         "MINIMUM": lambda a, b, c: np.minimum(a, b), "MAXIMUM": lambda a, b, c: np.maximum(a, b),
         "LESS_THAN": lambda a, b, c: (a < b).astype(np.float32),
         "GREATER_THAN": lambda a, b, c: (a > b).astype(np.float32),
         "ROUND": lambda a, b, c: np.floor(a + 0.5), "ABSOLUTE": lambda a, b, c: np.abs(a)}


def _math(node, socket, groups) -> _Value:
    operation = _MATH.get(node.operation)
    if operation is None:
        raise Unreadable(f"math node {node.name!r}: operation {node.operation} is not read")
    clamp = node.use_clamp
    values = [_socket(s, groups) for s in list(node.inputs)[:3]]
    return _combine(lambda a, b, c: np.clip(operation(a, b, c), 0, 1) if clamp else operation(a, b, c), *values)


_COLOUR_NODES = {"MATH": _math, "MIX": _mix, "MIX_RGB": _mix, "HUE_SAT": _hue_saturation, "GAMMA": _gamma,
                 "BRIGHTCONTRAST": _bright_contrast, "INVERT": _invert, "CURVE_RGB": _rgb_curves}
