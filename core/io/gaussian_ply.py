"""3DGS PLY files, as splat viewers (SuperSplat, PlayCanvas, Spark, gsplat.js) and the original 3DGS code load them.

Vertex properties, in this order, binary little-endian float32::

    x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 .. f_rest_{3*((d+1)^2-1)-1} opacity scale_0 scale_1 scale_2
    rot_0 rot_1 rot_2 rot_3

``f_rest`` is channel-major (all R coefficients, then G, then B); ``opacity`` is logit(α), ``scale_*`` log σ,
``rot_*`` the quaternion (w, x, y, z). Normals are zeros, unless the set has the fields ``nx``, ``ny``, ``nz``
(e.g. the normals of trained surface splats), which then fill them. Positions are local; the float64 origin
goes to the ``<name>.origin.json`` sidecar. Extra per-Gaussian fields (e.g. ``source``, ``classification``)
may be appended after ``rot_3`` as float32 properties — viewers ignore unknown properties.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
import plyfile

from core.errors import DataError, FormatError
from core.gaussians import GaussianSet, num_sh_bases, sh_degree_from_rest
from core.io.atomic import atomic_path
from core.io.origin import read_origin, remove_origin, write_origin
from core.io.ply import load_ply_data, scalar_column
from core.pointcloud import choose_origin


def gaussian_property_names(sh_degree: int) -> list[str]:
    """The 3DGS PLY vertex property names in viewer order for an SH degree (0–3)."""
    n_rest = 3 * (num_sh_bases(sh_degree) - 1)
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def gaussian_ply_rows(gs: GaussianSet, extra_fields: bool = False) -> tuple[list[str], np.ndarray]:
    """Property names and the (N, P) little-endian float32 rows of a 3DGS PLY for ``gs`` (what
    :func:`write_gaussian_ply` writes; the streamed conversion appends them chunk by chunk): position, normal (the
    ``nx/ny/nz`` fields, else zeros), SH DC, channel-major SH rest, logit opacity, log scales, quaternion, then with
    ``extra_fields`` the other fields in name order."""
    names = gaussian_property_names(gs.sh_degree)
    n = len(gs)
    # channel-major f_rest: (N, K-1, 3) -> (N, 3, K-1) -> flat
    rest = np.ascontiguousarray(gs.sh_rest.transpose(0, 2, 1)).reshape(n, 3 * gs.sh_rest.shape[1])  # type: ignore[union-attr]
    normal_names = ("nx", "ny", "nz")
    has_normals = all(k in gs.fields for k in normal_names)
    normals = (
        np.stack([gs.fields[k].astype(np.float32) for k in normal_names], axis=1)
        if has_normals
        else np.zeros((n, 3), np.float32)
    )
    parts = [gs.means.astype(np.float32), normals, gs.sh_dc, rest, gs.logit_opacities[:, None], gs.log_scales]
    rows = np.concatenate([*parts, gs.quats], axis=1).astype("<f4")
    extras = sorted(k for k in gs.fields if not (has_normals and k in normal_names))
    if extra_fields and extras:
        names = names + extras
        rows = np.concatenate([rows] + [gs.fields[k].astype("<f4")[:, None] for k in extras], axis=1)
    return names, np.ascontiguousarray(rows)


def write_gaussian_ply(
    path: str | PathLike[str],
    gaussians: GaussianSet,
    *,
    sh_degree: int | None = None,
    extra_fields: bool = False,
) -> Path:
    """Write a Gaussian set as a 3DGS PLY (atomically) plus the origin sidecar when the origin is not zero.

    ``sh_degree`` truncates or zero-pads SH (default: the set's degree). ``extra_fields`` appends the set's
    ``fields`` as float32 properties after ``rot_3``, except ``nx``/``ny``/``nz``, which go to the normal slots.
    Raises :class:`DataError` on NaN/inf parameters.
    """
    path = Path(path)
    gs = gaussians if sh_degree is None else gaussians.with_sh_degree(sh_degree)
    gs.validate(str(path))
    names, payload = gaussian_ply_rows(gs, extra_fields)
    n = len(gs)
    vertex = np.ascontiguousarray(payload).view(np.dtype([(name, "<f4") for name in names])).reshape(n)
    ply = plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")], text=False, byte_order="<")
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    if np.any(gs.origin != 0):
        write_origin(path, gs.origin)
    else:
        remove_origin(path)
    return path


def read_gaussian_ply(path: str | PathLike[str]) -> GaussianSet:
    """Read a 3DGS PLY (any SH degree 0–3) and its origin sidecar into a :class:`GaussianSet`.

    Properties beyond the 3DGS set are returned in ``fields``. Raises :class:`FormatError` naming the missing
    properties when the file is not a 3DGS PLY, :class:`DataError` on NaN/inf values.
    """
    path = Path(path)
    data = load_ply_data(path)
    if "vertex" not in data:
        raise FormatError("PLY file has no 'vertex' element", path)
    v = data["vertex"].data
    names = set(v.dtype.names or ())
    n_rest = sum(1 for name in names if name.startswith("f_rest_"))
    if n_rest % 3:
        raise FormatError(f"{n_rest} f_rest_* properties is not a multiple of 3", path)
    try:
        degree = sh_degree_from_rest(n_rest // 3)
    except DataError as err:
        raise FormatError(err.problem, path) from err
    required = [name for name in gaussian_property_names(degree) if name not in ("nx", "ny", "nz")]
    missing = [name for name in required if name not in names]
    if missing:
        shown = ", ".join(missing[:8]) + (" ..." if len(missing) > 8 else "")
        raise FormatError(f"not a 3DGS PLY: missing vertex properties {shown}", path)

    def cols(keys: list[str], dtype: type = np.float32) -> np.ndarray:
        if not keys:
            return np.zeros((len(v), 0), dtype)
        return np.stack([scalar_column(v, k, path).astype(dtype) for k in keys], axis=1)

    means = cols(["x", "y", "z"], np.float64)
    origin = read_origin(path)
    # World coordinates in the file (no sidecar, or a sidecar plus large offsets): move them to a local
    # origin in float64 now, so that every later float32 step (export, render) keeps the millimetres.
    shift = choose_origin(means) if np.isfinite(means).all() else np.zeros(3)
    means = means - shift
    origin = origin + shift
    k = num_sh_bases(degree) - 1
    rest = cols([f"f_rest_{i}" for i in range(3 * k)]).reshape(len(v), 3, k).transpose(0, 2, 1)
    known = set(gaussian_property_names(degree))
    fields = {name: np.asarray(v[name]) for name in v.dtype.names if name not in known}  # type: ignore[union-attr]
    gs = GaussianSet(
        means=means,
        log_scales=cols(["scale_0", "scale_1", "scale_2"]),
        quats=cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
        logit_opacities=scalar_column(v, "opacity", path).astype(np.float32),
        sh_dc=cols(["f_dc_0", "f_dc_1", "f_dc_2"]),
        sh_rest=np.ascontiguousarray(rest),
        origin=origin,
        fields=fields,
    )
    try:
        gs.validate()
    except DataError as err:
        raise DataError(err.problem, path) from err
    _check_ranges(gs, path)
    return gs


#: Log-scales above this (σ > e^30 m ≈ 1e13 m) are corrupt values, not Gaussians; exp() of them overflows
#: float32 in every renderer.
MAX_LOG_SCALE = 30.0


def _check_ranges(gs: GaussianSet, path: Path) -> None:
    """Refuse values that are finite but overflow later (huge log-scales)."""
    if len(gs) == 0:
        return
    worst = gs.log_scales.max(axis=1)
    bad = worst > MAX_LOG_SCALE
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise DataError(
            f"{int(bad.sum())} Gaussians have log-scales above {MAX_LOG_SCALE:g} (first: vertex {first}, "
            f"{float(worst[first]):.3g}); exp() would overflow",
            path,
        )
