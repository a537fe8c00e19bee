"""Gaussian splats as glTF 2.0 binary (``.glb``) with the ``KHR_gaussian_splatting`` extension: float32 attributes,
or one SPZ v2 stream through ``KHR_gaussian_splatting_compression_spz_2`` (``compression="spz"``, what CesiumJS draws).

Spec followed, and where it was learnt
--------------------------------------
- ``KHR_gaussian_splatting``, status "Release Candidate": KhronosGroup/glTF ``extensions/2.0/Khronos/
  KHR_gaussian_splatting/README.md`` and ``schema/mesh.primitive.KHR_gaussian_splatting.schema.json`` at commit
  63770cc ("Editorial review (#2567)", 2026-04-15; repository head 77b44be, 2026-07-17). Earlier drafts named the
  attributes ``_ROTATION`` / ``_SCALE`` and packed colour and opacity into ``COLOR_0``; the ratified names below
  replace them (CesiumJS still reads both prefixes for SH attributes).
- ``KHR_gaussian_splatting_compression_spz_2``, status "Draft": CesiumGS/glTF ``extensions/2.0/Khronos/
  KHR_gaussian_splatting_compression_spz_2/README.md`` and its ``schema/mesh.primitive.…schema.json`` at commit
  e0ec12a (branch ``cesium-native``, 2026-06-30; the README last changed in 7cff052, 2025-10-28; KhronosGroup/glTF
  holds the same text at e5f8ce1 / 3b2a287).
- CesiumJS's reader, CesiumGS/cesium ``packages/engine/Source/Scene/GaussianSplat3DTileContent.js``,
  ``GaussianSplatPrimitive.js``, ``GltfSpzLoader.js`` and ``GltfVertexBufferLoader.js`` (read through the code index,
  2026): it renders splats only when a tileset lists ``KHR_gaussian_splatting`` *and*
  ``KHR_gaussian_splatting_compression_spz_2`` in ``3DTILES_content_gltf``'s ``extensionsRequired``; an uncompressed
  primitive is drawn there as the spec's fallback point cloud (``COLOR_0``). Its transform chain (tile transform ·
  y-up→z-up · glTF node matrix) is the 3D Tiles one.
- The SH basis and signs are the spec's Appendix A (real SH with the Condon–Shortley phase); they equal the ones
  our renderer uses (:mod:`fusion.render.sh_basis`, graphdeco's), so coefficients are copied, not converted.
- Cross-checked (``scripts/check_gltf_tiles.sh``) against a second writer, PlayCanvas splat-transform 3.7.0's
  ``.glb`` output for the same splats: identical attributes once its 180° turn about z (it reads a 3DGS PLY as
  y-down) is applied; its ``COLOR_0`` keeps sRGB values where the spec asks for linear ones (ours are decoded).

No code was copied from any source.

Primitive layout we write (one mesh, one ``POINTS`` primitive, one node)
------------------------------------------------------------------------
===============================================  ======  ==========================  ==================================
attribute                                        type    component                   value (ours → glTF)
===============================================  ======  ==========================  ==================================
``POSITION``                                     VEC3    float                       ``means`` as float32 (frame: below)
``KHR_gaussian_splatting:ROTATION``              VEC4    float                       unit quaternion, glTF order
                                                                                     (x, y, z, w) from our (w, x, y, z)
``KHR_gaussian_splatting:SCALE``                 VEC3    float                       σ = exp(log_scales), linear metres
``KHR_gaussian_splatting:OPACITY``               SCALAR  float                       α = sigmoid(logit_opacities)
``KHR_gaussian_splatting:SH_DEGREE_0_COEF_0``    VEC3    float                       ``sh_dc`` (RGB)
``KHR_gaussian_splatting:SH_DEGREE_l_COEF_n``    VEC3    float                       ``sh_rest[:, l² + n − 1]`` (RGB),
                                                                                     n = 0..2l (m = −l..l), all of
                                                                                     degrees 1..L or none
``COLOR_0`` (fallback)                           VEC4    unsigned byte normalized    clamp(0.5 + C0 · sh_dc) decoded
                                                                                     sRGB → linear, alpha = α
===============================================  ======  ==========================  ==================================

Extension object: ``{"kernel": "ellipse", "colorSpace": "srgb_rec709_display" (default; 3DGS trained on sRGB
photos is display-referred sRGB), "projection": "perspective", "sortingMethod": "cameraDistance"}``; listed in
``extensionsUsed`` only (not required: a viewer without it shows the point cloud). The primitive references an
unlit material (``KHR_materials_unlit``) for that fallback; splat rendering ignores it as the spec says.

Frame: glTF is y-up, our data z-up. As the 3D Tiles specification's informative note recommends (and like
:mod:`fusion.mesh.export`), ``POSITION``, rotations and SH stay in the z-up frame unchanged, and the node's matrix
turns z-up into y-up, (x, y, z) → (x, z, −y) (a proper rotation: determinant +1, unit columns, as the extension
asks of node transforms). A 3D Tiles client applies its fixed y-up → z-up rotation after the node matrix, so the
two cancel and the tile frame is our z-up frame. Stand-alone glTF viewers show the splats upright.

SPZ-compressed primitive (``compression="spz"``)
-----------------------------------------------
The binary chunk holds one SPZ **version 2** file (gzip; the bytes :func:`fusion.spz_format.write_spz` writes at the
same fractional bits, whose encoding is Niantic's reference's) in buffer view **0** — CesiumJS's ``GltfSpzLoader`` reads
buffer view 0 whatever the extension says. The ``KHR_gaussian_splatting`` object gains ``"extensions":
{"KHR_gaussian_splatting_compression_spz_2": {"bufferView": 0}}`` (the schema's only, required, property; the README's
example lists the name without ``_2`` in ``extensionsUsed``, a slip: the schema, CesiumJS and we use the full name).
Both extensions are in ``extensionsUsed`` *and* ``extensionsRequired`` (no float data is left to fall back on).
Attributes are the ones the extension's mapping table lists, with accessors that have ``count`` = the stream's splat
count, the post-decompression ``type`` and ``componentType``, and no ``bufferView`` (the data comes from the stream):

======================================================  ======  ========================  =============================
attribute                                               type    component                 from the SPZ stream
======================================================  ======  ========================  =============================
``POSITION`` (``min``/``max``: the decoded bounds)      VEC3    float                     positions (fixed point)
``COLOR_0``                                             VEC4    unsigned byte normalized  0.5 + C0 · colour, alpha (α)
``KHR_gaussian_splatting:SCALE``                        VEC3    float                     exp(scales)
``KHR_gaussian_splatting:ROTATION``                     VEC4    float                     rotations (x, y, z, w)
``KHR_gaussian_splatting:SH_DEGREE_l_COEF_n``, l ≥ 1    VEC3    float                     sh[(l² − 1 + n) · 3 …]
======================================================  ======  ========================  =============================

No ``OPACITY`` and no ``SH_DEGREE_0_COEF_0``: the mapping puts α and the DC term in ``COLOR_0``, and CesiumJS's
``GltfVertexBufferLoader`` fills only the semantics above from the stream. (The README's table lists degree 1 as
COEF_0, COEF_2, COEF_3, a typo; CesiumJS indexes coefficient n at 3n within its degree, as we write.)

Axes: the README asks SPZ's ``PackOptions``/``UnpackOptions`` to name ``LUF`` (which makes Niantic's library store
x and z negated, its "RUB" frame, and negate them back on reading); CesiumJS decodes with ``coordinateSystem:
"UNSPECIFIED"`` (no conversion), so the stored values *are* its glTF-primitive coordinates. We write what CesiumJS
reads: the primitive's (z-up) coordinates unchanged, the same node matrix as the float form, SH unchanged. A reader
that applies the README's LUF conversion would show the splats turned 180° about the glTF y (up) axis, i.e. about the
tile frame's vertical; ``asset.extras.spz.axes`` says ``"as stored"``.

Precision (SPZ): positions are fixed point about the *primitive's* origin (for a tile: the tile frame's origin, i.e.
the set's origin, not the tile's centre) with the most fractional bits the primitive's coordinates allow
(:func:`fusion.spz_format.finest_fractional_bits`): ±2^−(b+1) m per axis, i.e. ±3.8 µm within ±64 m, ±30 µm within
±512 m, ±0.12 mm within ±2 048 m, ±0.49 mm within ±8 192 m (fewer than 12 bits with a warning); α ±1/510, colour
±0.0131 (|f_dc| ≤ 3.33), σ ±3.2 %, rotation x, y, z ±1/255, SH rest ±0.035 / ±0.066 (see :mod:`fusion.spz_format`;
values outside SPZ's ranges are clipped with a warning). Sizes against float32 tiles:
docs/experiments/2026-11-27-domain-defaults.md.

Precision (float32): positions are float32 copies of the float64 input (< 0.5 ulp: 3e-5 m at 500 m); σ, α,
quaternions and SH are float32. Reading back (:meth:`SplatPrimitive.to_gaussians`) gives log σ and logit α again;
logit α loses precision where α rounds near 1 in float32 (|logit| ≳ 10), so compare opacities as α.
"""

from __future__ import annotations

import math
import struct
import tempfile
import zlib
from dataclasses import dataclass, field
from enum import Enum
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import DataError, FormatError, InputFileError
from core.gaussians import SH_C0, GaussianSet, logit, sigmoid
from fusion.render.sh_basis import sh_basis_into
from fusion.sphere_lattice import fibonacci_sphere

EXTENSION = "KHR_gaussian_splatting"
"""The glTF extension name."""

SPEC_REVISION = "KHR_gaussian_splatting Release Candidate, KhronosGroup/glTF@63770cc (2026-04-15)"
"""The revision of the extension text this module follows (recorded in each file's ``asset.extras``)."""

SPZ_EXTENSION = "KHR_gaussian_splatting_compression_spz_2"
"""The glTF extension carrying an SPZ v2 stream inside a ``KHR_gaussian_splatting`` primitive."""

SPZ_SPEC_REVISION = (
    "KHR_gaussian_splatting_compression_spz_2 Draft, CesiumGS/glTF@e0ec12a (cesium-native, 2026-06-30; README "
    "as of 7cff052, 2025-10-28); axes as CesiumJS decodes them (no LUF flip)"
)
"""The revision of the SPZ extension text this module follows (recorded in ``asset.extras.spz``)."""

PREFIX = EXTENSION + ":"
ATTR_ROTATION = PREFIX + "ROTATION"
ATTR_SCALE = PREFIX + "SCALE"
ATTR_OPACITY = PREFIX + "OPACITY"

Z_UP_TO_Y_UP = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
"""The node matrix, glTF column-major: (x, y, z) → (x, z, −y)."""

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])
"""The fixed rotation 3D Tiles applies to glTF content (row-major as printed in the 3D Tiles 1.1 spec, §glTF
transforms): (x, y, z) → (x, −z, y)."""

_FLOAT, _UBYTE = 5126, 5121
_ARRAY_BUFFER = 34962
_POINTS = 0
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_DTYPES = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}


class GltfCompression(str, Enum):
    """How splat attributes are stored: float32 accessors, or one SPZ v2 stream (CesiumJS draws only this)."""

    NONE = "none"
    SPZ = "spz"


class ColorSpace(str, Enum):
    """``colorSpace`` of the extension: how the reconstructed splat colours are to be read."""

    SRGB = "srgb_rec709_display"
    LINEAR = "lin_rec709_display"


def sh_attribute(degree: int, coef: int) -> str:
    """``KHR_gaussian_splatting:SH_DEGREE_<degree>_COEF_<coef>`` (coef = m + degree, 0..2·degree)."""
    return f"{PREFIX}SH_DEGREE_{degree}_COEF_{coef}"


def sh_index(degree: int, coef: int) -> int:
    """Index into our (N, K, 3) coefficients, DC first, of one SH attribute: degree² + coef."""
    return degree * degree + coef


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted (IEC 61966-2-1), values in [0, 1]."""
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


# -- SH rotation -------------------------------------------------------------------------------------------------


def sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """Real SH basis values (M, (degree+1)²) at unit directions ``dirs`` (M, 3), the spec's Appendix A formulas
    (the renderer's basis, :mod:`fusion.render.sh_basis`)."""
    d = np.asarray(dirs, np.float64)
    out = np.empty(((degree + 1) ** 2, len(d)))
    sh_basis_into(degree, d[:, 0], d[:, 1], d[:, 2], out)
    return np.ascontiguousarray(out.T)


def rotate_sh_rest(sh_rest: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """SH coefficients (N, K−1, 3) (degrees 1..3, our layout) re-expressed in a frame rotated by ``rotation``.

    ``rotation``: (3, 3) proper rotation taking old-frame vectors to new-frame vectors (d_new = R · d_old). The
    result gives, at d_new, the colour the input gave at d_old. Each degree's (2l+1)² matrix is found by least
    squares on 64 directions (the basis is polynomial, so the fit is exact to float64 rounding); the DC term
    does not change under rotation.
    """
    rest = np.asarray(sh_rest, dtype=np.float64)
    k = rest.shape[1]
    if k == 0:
        return rest.astype(np.float32)
    degree = int(round(math.sqrt(k + 1))) - 1
    dirs_new = fibonacci_sphere(64)
    dirs_old = dirs_new @ np.asarray(rotation, np.float64)  # rows: Rᵀ · d_new
    basis_new = sh_basis(dirs_new, degree)
    basis_old = sh_basis(dirs_old, degree)
    out = np.empty_like(rest)
    for band in range(1, degree + 1):
        sl = slice(band * band, (band + 1) ** 2)
        # basis_old[:, sl] = basis_new[:, sl] · X, then colour = Σ c · Y_old = Σ (X c) · Y_new
        x, *_ = np.linalg.lstsq(basis_new[:, sl], basis_old[:, sl], rcond=None)
        out[:, sl.start - 1 : sl.stop - 1] = np.einsum("jk,nkc->njc", x, rest[:, sl.start - 1 : sl.stop - 1])
    return out.astype(np.float32)


# -- writing -----------------------------------------------------------------------------------------------------


def encode_splat_glb(
    gaussians: GaussianSet,
    color_space: ColorSpace = ColorSpace.SRGB,
    name: str = "splats",
    extras: dict[str, Any] | None = None,
    compression: GltfCompression = GltfCompression.NONE,
) -> bytes:
    """The GLB bytes of one splat primitive holding every Gaussian of ``gaussians`` (layout: module docstring).

    Positions are ``gaussians.means`` in their own (z-up) frame; ``gaussians.origin`` is *not* written (the caller
    places the frame, e.g. a 3D Tiles ``transform``). ``extras``: JSON-able values for ``asset.extras``.
    ``compression``: ``none`` (float32 attributes) or ``spz`` (one SPZ v2 stream through
    ``KHR_gaussian_splatting_compression_spz_2``, what CesiumJS draws; precision: :mod:`fusion.spz_format`, with
    the most fractional bits the positions allow). Raises :class:`DataError` for an empty set, NaN/inf values or a
    zero quaternion; :class:`FormatError` (SPZ) for positions beyond ±8 388 607 m.
    """
    import pygltflib as gl  # lazy: only exports need it

    if len(gaussians) == 0:
        raise DataError("a glTF splat primitive needs at least one Gaussian, got an empty set")
    gaussians.validate("glTF export")
    color_space = ColorSpace(color_space)
    compression = GltfCompression(compression)
    extension: dict[str, Any] = {
        "kernel": "ellipse",
        "colorSpace": color_space.value,
        "projection": "perspective",
        "sortingMethod": "cameraDistance",
    }
    asset_extras: dict[str, Any] = {"spec": SPEC_REVISION}
    if compression is GltfCompression.SPZ:
        accessors, views, attributes, blob, bits = _spz_parts(gaussians, name)
        extension["extensions"] = {SPZ_EXTENSION: {"bufferView": 0}}
        asset_extras["spz"] = {"spec": SPZ_SPEC_REVISION, "version": 2, "fractionalBits": bits, "axes": "as stored"}
        used, required = [EXTENSION, SPZ_EXTENSION, "KHR_materials_unlit"], [EXTENSION, SPZ_EXTENSION]
    else:
        accessors, views, attributes, blob = _float_parts(gaussians, color_space)
        used, required = [EXTENSION, "KHR_materials_unlit"], []
    doc = gl.GLTF2(
        asset=gl.Asset(version="2.0", generator=generator(), extras={**asset_extras, **(extras or {})}),
        extensionsUsed=used,
        extensionsRequired=required,
        scene=0,
        scenes=[gl.Scene(nodes=[0])],
        nodes=[gl.Node(name=name, mesh=0, matrix=list(Z_UP_TO_Y_UP))],
        meshes=[
            gl.Mesh(
                name=name,
                primitives=[
                    gl.Primitive(
                        attributes=gl.Attributes(**attributes),
                        mode=_POINTS,
                        material=0,
                        extensions={EXTENSION: extension},
                    )
                ],
            )
        ],
        materials=[gl.Material(extensions={"KHR_materials_unlit": {}})],
        accessors=accessors,
        bufferViews=views,
        buffers=[gl.Buffer(byteLength=len(blob))],
    )
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())


def _float_parts(gaussians: GaussianSet, color_space: ColorSpace) -> tuple[list, list, dict[str, int], bytearray]:
    """Accessors, buffer views, attribute map and binary chunk of the uncompressed layout."""
    import pygltflib as gl

    blob = bytearray()
    accessors, views, attributes = [], [], {}
    for semantic, values, kind, component, normalized in _columns(gaussians, color_space):
        data = np.ascontiguousarray(values, dtype="<f4" if component == _FLOAT else "<u1").tobytes()
        views.append(gl.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=_ARRAY_BUFFER))
        acc = gl.Accessor(bufferView=len(views) - 1, componentType=component, count=len(gaussians), type=kind)
        if normalized:
            acc.normalized = True
        if semantic == "POSITION":  # required by glTF for POSITION: the exact float32 bounds
            acc.min = [float(v) for v in values.min(axis=0)]
            acc.max = [float(v) for v in values.max(axis=0)]
        accessors.append(acc)
        attributes[semantic] = len(accessors) - 1
        blob += data
        blob += b"\0" * (-len(blob) % 4)  # every view starts 4-byte aligned (all components are ≤ 4 bytes)
    return accessors, views, attributes, blob


def _spz_parts(gaussians: GaussianSet, name: str) -> tuple[list, list, dict[str, int], bytearray, int]:
    """Accessors (no buffer views: the data is in the SPZ stream), the one buffer view (index 0, where CesiumJS
    looks), attribute map, binary chunk (the gzipped SPZ v2 file, padded to 4 bytes) and the fractional bits."""
    import pygltflib as gl

    from fusion.spz_format import EXPORT_SH1_BITS, EXPORT_SH_REST_BITS, encode_spz, finest_fractional_bits

    header, payload = encode_spz(
        gaussians, version=2, fractional_bits=finest_fractional_bits(gaussians.means), name=f"glTF SPZ {name}",
        sh1_bits=EXPORT_SH1_BITS, sh_rest_bits=EXPORT_SH_REST_BITS,
    )  # fmt: skip
    compressor = zlib.compressobj(6, zlib.DEFLATED, 16 + zlib.MAX_WBITS, 9)  # gzip, as fusion.spz_format writes
    stream = compressor.compress(payload) + compressor.flush()
    blob = bytearray(stream) + b"\0" * (-len(stream) % 4)
    views = [gl.BufferView(buffer=0, byteOffset=0, byteLength=len(stream))]
    n, step = len(gaussians), 2.0**-header.fractional_bits
    stored = np.copysign(np.floor(np.abs(gaussians.means / step) + 0.5), gaussians.means) * step  # what SPZ decodes
    position = gl.Accessor(componentType=_FLOAT, count=n, type="VEC3")
    position.min = [float(v) for v in stored.min(axis=0).astype(np.float32)]
    position.max = [float(v) for v in stored.max(axis=0).astype(np.float32)]
    color = gl.Accessor(componentType=_UBYTE, count=n, type="VEC4", normalized=True)
    accessors = [position, color]
    semantics = ["POSITION", "COLOR_0"]
    for semantic, kind in ((ATTR_SCALE, "VEC3"), (ATTR_ROTATION, "VEC4")):
        accessors.append(gl.Accessor(componentType=_FLOAT, count=n, type=kind))
        semantics.append(semantic)
    for degree in range(1, gaussians.sh_degree + 1):
        for coef in range(2 * degree + 1):
            accessors.append(gl.Accessor(componentType=_FLOAT, count=n, type="VEC3"))
            semantics.append(sh_attribute(degree, coef))
    for acc in accessors:
        acc.byteOffset = None  # glTF: byteOffset depends on bufferView, which these accessors have not
    return accessors, views, {s: i for i, s in enumerate(semantics)}, blob, header.fractional_bits


def _columns(gaussians: GaussianSet, color_space: ColorSpace) -> list[tuple[str, np.ndarray, str, int, bool]]:
    """(semantic, values, accessor type, component type, normalized) of every attribute, in file order."""
    quats = gaussians.quats.astype(np.float64)
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    columns: list[tuple[str, np.ndarray, str, int, bool]] = [
        ("POSITION", gaussians.means.astype(np.float32), "VEC3", _FLOAT, False),
        (ATTR_ROTATION, quats[:, [1, 2, 3, 0]].astype(np.float32), "VEC4", _FLOAT, False),
        (ATTR_SCALE, np.exp(gaussians.log_scales.astype(np.float64)).astype(np.float32), "VEC3", _FLOAT, False),
        (ATTR_OPACITY, sigmoid(gaussians.logit_opacities).astype(np.float32), "SCALAR", _FLOAT, False),
    ]
    coeffs = gaussians.sh_coeffs
    for degree in range(gaussians.sh_degree + 1):
        for coef in range(2 * degree + 1):
            columns.append((sh_attribute(degree, coef), coeffs[:, sh_index(degree, coef)], "VEC3", _FLOAT, False))
    base = np.clip(0.5 + SH_C0 * gaussians.sh_dc.astype(np.float64), 0.0, 1.0)
    linear = srgb_to_linear(base) if color_space is ColorSpace.SRGB else base
    rgba = np.c_[linear, sigmoid(gaussians.logit_opacities)]
    columns.append(("COLOR_0", np.rint(rgba * 255.0).astype(np.uint8), "VEC4", _UBYTE, True))
    return columns


def generator() -> str:
    """``hybridsplat <version>`` (the installed distribution's), written as the files' generator."""
    try:
        from importlib.metadata import version

        return f"hybridsplat {version('hybridsplat')}"
    except Exception:  # not installed as a distribution (source checkout)
        return "hybridsplat"


# -- reading -----------------------------------------------------------------------------------------------------


@dataclass
class SplatPrimitive:
    """One decoded ``KHR_gaussian_splatting`` primitive (N splats), values as stored (glTF conventions).

    positions (N, 3) float32 in the primitive's frame; rotations (N, 4) float32 (x, y, z, w); scales (N, 3)
    float32 σ (linear); opacities (N,) float32 α; sh (N, K, 3) float32, DC first, our coefficient order;
    colors (N, 4) float32 in [0, 1] (``COLOR_0``) or None; node_matrix (4, 4) float64, the node's global transform
    (row-major numpy, i.e. glTF's column-major list transposed); extension: the extension object;
    extensions_used: the file's ``extensionsUsed``; asset_extras: ``asset.extras``; compression: ``none`` or
    ``spz`` (then every value is the SPZ stream's, decoded by :func:`fusion.spz_format.read_spz`: SH DC and α as
    SPZ quantises them, ``colors`` = clamp(0.5 + C0 · DC) with α, as the extension's attribute mapping says);
    spz_fractional_bits: the stream's fixed-point precision (None when uncompressed).
    """

    positions: np.ndarray
    rotations: np.ndarray
    scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    colors: np.ndarray | None
    node_matrix: np.ndarray
    extension: dict[str, Any]
    extensions_used: list[str] = field(default_factory=list)
    asset_extras: dict[str, Any] = field(default_factory=dict)
    compression: str = GltfCompression.NONE.value
    spz_fractional_bits: int | None = None

    def __len__(self) -> int:
        return len(self.positions)

    def to_gaussians(self) -> GaussianSet:
        """A :class:`GaussianSet` in the primitive's frame (origin zero): log σ, logit α, quaternions (w, x, y, z).
        σ = 0 (allowed by the spec) becomes the smallest float32 before the log."""
        tiny = np.finfo(np.float32).tiny
        return GaussianSet(
            self.positions.astype(np.float64),
            np.log(np.maximum(self.scales.astype(np.float64), tiny)),
            self.rotations[:, [3, 0, 1, 2]],
            logit(self.opacities),
            self.sh[:, 0],
            self.sh[:, 1:],
        )


def read_splat_glb(source: str | PathLike[str] | bytes) -> SplatPrimitive:
    """Decode the first ``KHR_gaussian_splatting`` primitive of a GLB (a path, or the bytes).

    Reads the uncompressed attributes in every component type the spec allows (normalized integers decoded as
    glTF defines). Raises :class:`FormatError` naming the file for a file that is not GLB 2.0, has no splat
    primitive, lacks a required attribute, defines SH degrees partially, or uses sparse accessors or external
    buffers; :class:`InputFileError` when the file cannot be read.
    """
    import pygltflib as gl

    path = None if isinstance(source, (bytes, bytearray)) else Path(source)
    if path is not None:
        if not path.is_file():
            raise InputFileError("file does not exist" if not path.exists() else "is not a file", path)
        data = path.read_bytes()
    else:
        data = bytes(source)  # type: ignore[arg-type]
    _check_glb_header(data, path)
    try:
        doc = gl.GLTF2.load_from_bytes(data)
    except Exception as err:  # pygltflib raises bare exceptions on malformed JSON
        raise FormatError(f"not a readable GLB ({type(err).__name__}: {err})", path) from err
    blob = doc.binary_blob() or b""
    for mesh_index, mesh in enumerate(doc.meshes or []):
        for prim in mesh.primitives or []:
            if prim.extensions and EXTENSION in prim.extensions:
                return _decode_primitive(doc, prim, blob, _node_matrix(doc, mesh_index), path)
    raise FormatError(f"no mesh primitive carries the {EXTENSION} extension", path)


def _check_glb_header(data: bytes, path: Path | None) -> None:
    if len(data) < 20 or data[:4] != b"glTF":
        raise FormatError("not a GLB file (no 'glTF' magic)", path)
    _magic, version, length = struct.unpack_from("<4sII", data, 0)
    if version != 2:
        raise FormatError(f"GLB version {version}, expected 2", path)
    if length != len(data):
        raise FormatError(f"GLB header says {length} bytes, the file has {len(data)} (truncated?)", path)


def _node_matrix(doc: Any, mesh_index: int) -> np.ndarray:
    """Global transform (4, 4) of the first node instantiating the mesh (identity when none does)."""
    parents = {c: i for i, node in enumerate(doc.nodes or []) for c in (node.children or [])}
    for i, node in enumerate(doc.nodes or []):
        if node.mesh == mesh_index:
            m = np.eye(4)
            j: int | None = i
            while j is not None:
                m = _local_matrix(doc.nodes[j]) @ m
                j = parents.get(j)
            return m
    return np.eye(4)


def _local_matrix(node: Any) -> np.ndarray:
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T  # glTF is column-major
    from scipy.spatial.transform import Rotation

    m = np.eye(4)
    s = np.asarray(node.scale if node.scale is not None else [1, 1, 1], np.float64)
    q = np.asarray(node.rotation if node.rotation is not None else [0, 0, 0, 1], np.float64)  # x, y, z, w
    m[:3, :3] = Rotation.from_quat(q).as_matrix() * s
    m[:3, 3] = node.translation if node.translation is not None else [0, 0, 0]
    return m


def _decode_primitive(doc: Any, prim: Any, blob: bytes, node_matrix: np.ndarray, path: Path | None) -> SplatPrimitive:
    attrs = {k: v for k, v in vars(prim.attributes).items() if v is not None}
    if prim.mode != _POINTS:  # glTF's default mode (absent) is TRIANGLES
        raise FormatError(f"splat primitive mode must be POINTS (0), got {prim.mode}", path)
    spz = ((prim.extensions[EXTENSION] or {}).get("extensions") or {}).get(SPZ_EXTENSION)
    if spz is not None:
        return _decode_spz_primitive(doc, prim, attrs, spz, blob, node_matrix, path)
    required = ["POSITION", ATTR_ROTATION, ATTR_SCALE, ATTR_OPACITY, sh_attribute(0, 0)]
    missing = [a for a in required if a not in attrs]
    if missing:
        found = ", ".join(sorted(attrs)) or "none"
        raise FormatError(f"splat primitive lacks attribute(s) {', '.join(missing)} (has: {found})", path)
    degree = 0
    for d in (1, 2, 3):
        present = [sh_attribute(d, c) in attrs for c in range(2 * d + 1)]
        if all(present) and degree == d - 1:
            degree = d
        elif any(present):
            raise FormatError(f"SH degree {d} is defined partially or without the lower degrees", path)

    def get(semantic: str, kind: str) -> np.ndarray:
        return _read_accessor(doc, attrs[semantic], blob, kind, semantic, path)

    positions = get("POSITION", "VEC3")
    n = len(positions)
    sh = np.stack(
        [get(sh_attribute(d, c), "VEC3") for d in range(degree + 1) for c in range(2 * d + 1)], axis=1
    ).astype(np.float32)
    out = SplatPrimitive(
        positions=positions.astype(np.float32),
        rotations=get(ATTR_ROTATION, "VEC4").astype(np.float32),
        scales=get(ATTR_SCALE, "VEC3").astype(np.float32),
        opacities=get(ATTR_OPACITY, "SCALAR").reshape(-1).astype(np.float32),
        sh=sh,
        colors=get("COLOR_0", "VEC4").astype(np.float32) if "COLOR_0" in attrs else None,
        node_matrix=node_matrix,
        extension=dict(prim.extensions[EXTENSION] or {}),
        extensions_used=list(doc.extensionsUsed or []),
        asset_extras=dict(doc.asset.extras or {}) if doc.asset is not None else {},
    )
    for name in ("rotations", "scales", "opacities", "sh"):
        if len(getattr(out, name)) != n:
            raise FormatError(f"attribute {name} has {len(getattr(out, name))} values for {n} positions", path)
    return out


def _decode_spz_primitive(
    doc: Any, prim: Any, attrs: dict[str, int], spz: dict[str, Any], blob: bytes, node_matrix: np.ndarray, path: Any
) -> SplatPrimitive:
    """A primitive whose values come from its ``KHR_gaussian_splatting_compression_spz_2`` stream."""
    stream = spz_stream(doc, spz, blob, path)
    data = _decode_spz_bytes(stream, path)
    n, degree = data.header.num_points, data.header.sh_degree
    required = ["POSITION", "COLOR_0", ATTR_SCALE, ATTR_ROTATION]
    required += [sh_attribute(d, c) for d in range(1, degree + 1) for c in range(2 * d + 1)]
    missing = [a for a in required if a not in attrs]
    if missing:
        raise FormatError(f"SPZ splat primitive lacks attribute(s) {', '.join(missing)}", path)
    for semantic in required:
        count = doc.accessors[attrs[semantic]].count
        if count != n:
            raise FormatError(f"{semantic}: accessor count {count}, the SPZ stream holds {n} splats", path)
    alphas = data.alphas.astype(np.float32)
    colors = np.c_[np.clip(0.5 + SH_C0 * data.sh_dc, 0.0, 1.0), alphas].astype(np.float32)
    return SplatPrimitive(
        positions=data.positions.astype(np.float32),
        rotations=data.quats[:, [1, 2, 3, 0]].astype(np.float32),
        scales=np.exp(data.log_scales).astype(np.float32),
        opacities=alphas,
        sh=np.concatenate([data.sh_dc[:, None, :], data.sh_rest], axis=1).astype(np.float32),
        colors=colors,
        node_matrix=node_matrix,
        extension=dict(prim.extensions[EXTENSION] or {}),
        extensions_used=list(doc.extensionsUsed or []),
        asset_extras=dict(doc.asset.extras or {}) if doc.asset is not None else {},
        compression=GltfCompression.SPZ.value,
        spz_fractional_bits=data.header.fractional_bits,
    )


def spz_stream(doc: Any, spz: dict[str, Any], blob: bytes, path: Any = None) -> bytes:
    """The SPZ file bytes (gzip) that the extension object ``spz`` points at, from the GLB's binary chunk."""
    index = spz.get("bufferView") if isinstance(spz, dict) else None
    if not isinstance(index, int) or not 0 <= index < len(doc.bufferViews or []):
        raise FormatError(f"{SPZ_EXTENSION}.bufferView {index!r} is not a buffer view of the file", path)
    view = doc.bufferViews[index]
    if view.buffer != 0 or (doc.buffers[view.buffer].uri not in (None, "")):
        raise FormatError(f"{SPZ_EXTENSION}: data outside the GLB binary chunk is not supported", path)
    start = view.byteOffset or 0
    if start + view.byteLength > len(blob):
        raise FormatError(f"{SPZ_EXTENSION}: buffer view {index} runs past the binary chunk", path)
    return bytes(blob[start : start + view.byteLength])


def _decode_spz_bytes(stream: bytes, path: Any) -> Any:
    """:func:`fusion.spz_format.read_spz` of in-memory SPZ bytes (it reads files: a private temporary one)."""
    from fusion.spz_format import read_spz

    with tempfile.TemporaryDirectory(prefix="hybridsplat-spz-") as tmp:
        spz_path = Path(tmp) / "stream.spz"
        spz_path.write_bytes(stream)
        try:
            return read_spz(spz_path)
        except (FormatError, InputFileError) as err:
            raise FormatError(f"{SPZ_EXTENSION} stream: {err.problem}", path) from None


def _read_accessor(doc: Any, index: int, blob: bytes, kind: str, semantic: str, path: Path | None) -> np.ndarray:
    """(count, components) float64 (normalized integers decoded per glTF §3.11) of one accessor."""
    try:
        acc = doc.accessors[index]
    except (IndexError, TypeError):
        raise FormatError(f"{semantic}: accessor {index} does not exist", path) from None
    if acc.type != kind and not (kind == "VEC4" and semantic == "COLOR_0" and acc.type == "VEC3"):
        raise FormatError(f"{semantic}: accessor type {acc.type}, expected {kind}", path)
    if acc.sparse is not None:
        raise FormatError(f"{semantic}: sparse accessors are not supported", path)
    if acc.componentType not in _DTYPES:
        raise FormatError(f"{semantic}: unknown componentType {acc.componentType}", path)
    dtype = np.dtype(_DTYPES[acc.componentType])
    comps = _COMPONENTS[acc.type]
    if acc.bufferView is None:
        return np.zeros((acc.count, comps))
    view = doc.bufferViews[acc.bufferView]
    if view.buffer != 0 or (doc.buffers[view.buffer].uri not in (None, "")):
        raise FormatError(f"{semantic}: data outside the GLB binary chunk is not supported", path)
    stride = view.byteStride or dtype.itemsize * comps
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    end = start + stride * (acc.count - 1) + dtype.itemsize * comps if acc.count else start
    if end > len(blob) or end - (view.byteOffset or 0) > view.byteLength:
        raise FormatError(f"{semantic}: accessor runs past its buffer view or the binary chunk", path)
    raw = np.ndarray((acc.count, comps), dtype=dtype, buffer=blob, offset=start, strides=(stride, dtype.itemsize))
    values = raw.astype(np.float64)
    if acc.normalized:
        if dtype.kind == "u":
            values /= float(np.iinfo(dtype).max)
        else:
            values = np.maximum(values / float(np.iinfo(dtype).max), -1.0)
    if semantic == "COLOR_0" and comps == 3:
        values = np.c_[values, np.ones(len(values))]
    return values
