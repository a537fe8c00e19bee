"""CPU ray tracer over open3d's ``RaycastingScene`` (Embree): photos, z-depth and material labels.

open3d intersects in float32; every hit is re-intersected in float64 with the triangle open3d reports, so hit
points lie on the float64 ground-truth mesh to ~1e-12 relative, whatever the float32 rounding.

Shading (linear RGB): Lambert under a sun with shadow rays plus sky ambient; glossy surfaces add a Blinn-Phong
highlight and a Fresnel-weighted traced reflection; mirrors trace the reflected ray; glass mixes traced
reflection and refraction with Schlick's Fresnel term (total internal reflection included). Secondary rays of
one bounce level are traced as one batch. Open3d's per-ray results do not depend on thread scheduling, and
every reduction here is in a fixed order, so renders are deterministic.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from core.cameras import Camera, View
from core.errors import DataError
from data_synth.geometry import SceneMesh
from data_synth.lighting import Environment
from data_synth.materials import BACKGROUND_LABEL, TARGET_MATERIAL_ID, Material, Shading
from data_synth.targets import TargetSet
from data_synth.textures import TextureField

_CHUNK = 1 << 18


@dataclass(frozen=True)
class Hits:
    """First hits of a batch of N rays.

    hit: (N,) bool. t: (N,) float64 ray parameter (= distance for unit directions; inf where no hit).
    points: (N, 3) float64 local hit points (undefined where no hit). face: (N,) int64 face index (-1 if none).
    material: (N,) int32 material id (255 if none). normal: (N, 3) float64 unit geometric face normal.
    """

    hit: np.ndarray
    t: np.ndarray
    points: np.ndarray
    face: np.ndarray
    material: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True)
class RenderSettings:
    """supersample: S for S×S jittered samples per pixel. max_depth: reflection/refraction bounces.
    exposure: multiplies radiance before tone mapping."""

    supersample: int = 2
    max_depth: int = 4
    exposure: float = 1.0


@dataclass(frozen=True)
class ViewRender:
    """One rendered view: image (H, W, 3) uint8 sRGB; depth (H, W) float32 z-depth metres (0 = no surface);
    labels (H, W) uint8 material id (255 = background), both at pixel centres."""

    image: np.ndarray
    depth: np.ndarray
    labels: np.ndarray


def linear_to_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear RGB (any shape) → 8-bit sRGB (IEC 61966-2-1 transfer curve), clamped to [0, 1] first."""
    c = np.clip(linear, 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def srgb8_to_linear(srgb: np.ndarray) -> np.ndarray:
    """8-bit sRGB → linear float64 in [0, 1]."""
    s = np.asarray(srgb, dtype=np.float64) / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def camera_rays(camera: Camera, view: View, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays through continuous pixel coordinates (N, 2) (COLMAP convention, pixel centres at +0.5).

    Returns origins (N, 3), unit directions (N, 3) in the local frame, and ``z_per_t`` (N,): the z-depth
    gained per unit of ray length (so z-depth = t * z_per_t). All float64.
    """
    d_cam = camera.unproject(np.asarray(pixels, dtype=np.float64), 1.0)  # z = 1
    norm = np.linalg.norm(d_cam, axis=1)
    unit = d_cam / norm[:, None]
    dirs = _rows_times(unit, view.rotation)  # R^T d for row vectors
    origins = np.broadcast_to(view.center, dirs.shape).copy()
    return origins, dirs, 1.0 / norm


def _raycasting_scene(vertices: np.ndarray, faces: np.ndarray) -> o3d.t.geometry.RaycastingScene:
    scene = o3d.t.geometry.RaycastingScene()
    tmesh = o3d.t.geometry.TriangleMesh()
    tmesh.vertex.positions = o3d.core.Tensor(vertices.astype(np.float32))
    tmesh.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.int32))
    scene.add_triangles(tmesh)
    return scene


def _rows_times(v: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``v @ m`` for (N, 3) @ (3, 3) by broadcasting: BLAS threads stall on busy cores and may round differently
    with the thread count; this is deterministic everywhere."""
    return v[:, 0:1] * m[0] + v[:, 1:2] * m[1] + v[:, 2:3] * m[2]


def _reflect(d: np.ndarray, n: np.ndarray) -> np.ndarray:
    return d - 2.0 * np.sum(d * n, axis=1, keepdims=True) * n


def _schlick(f0: float | np.ndarray, cos: np.ndarray) -> np.ndarray:
    return f0 + (1.0 - f0) * (1.0 - np.clip(cos, 0.0, 1.0)) ** 5


class RayTracer:
    """Renders one :class:`SceneMesh` with its materials, textures and environment.

    ``eps`` (metres) offsets secondary-ray origins off surfaces; default 1e-6 of the scene diagonal. ``targets``:
    the coded targets among the mesh's faces (material :data:`~data_synth.materials.TARGET_MATERIAL_ID`), whose
    albedo is their marker's bitmap.
    """

    def __init__(
        self,
        mesh: SceneMesh,
        materials: Mapping[int, Material],
        textures: TextureField,
        environment: Environment,
        settings: RenderSettings | None = None,
        eps: float | None = None,
        targets: TargetSet | None = None,
    ) -> None:
        self.mesh = mesh
        self.targets = targets
        self.materials = dict(materials)
        self.textures = textures
        self.env = environment
        self.settings = settings or RenderSettings()
        diag = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
        self.eps = eps if eps is not None else max(1e-6 * diag, 1e-7)
        self._normals = mesh.face_normals()
        self._v0 = mesh.triangles[:, 0]
        unknown = set(np.unique(mesh.face_material).tolist()) - set(self.materials)
        if unknown:
            raise DataError(f"mesh uses material ids without a legend entry: {sorted(unknown)}")
        self._scene = _raycasting_scene(mesh.vertices, mesh.faces)
        # Clear glass transmits most sunlight: it casts no shadow (caustics are not modelled).
        glass_ids = [i for i, m in self.materials.items() if m.shading is Shading.GLASS]
        opaque = ~np.isin(mesh.face_material, glass_ids)
        self._shadow_scene = _raycasting_scene(mesh.vertices, mesh.faces[opaque]) if opaque.any() else None

    # -- intersection ---------------------------------------------------------------------------
    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> Hits:
        """First hits of rays (N, 3) origins and unit directions, float64 (see :class:`Hits`)."""
        n = len(origins)
        t_all = np.full(n, np.inf)
        face_all = np.full(n, -1, np.int64)
        for s in range(0, n, _CHUNK):
            rays = np.concatenate([origins[s : s + _CHUNK], dirs[s : s + _CHUNK]], axis=1).astype(np.float32)
            ans = self._scene.cast_rays(o3d.core.Tensor(rays))
            t = ans["t_hit"].numpy().astype(np.float64)
            ok = np.isfinite(t)
            t_all[s : s + _CHUNK] = t
            face_all[s : s + _CHUNK] = np.where(ok, ans["primitive_ids"].numpy().astype(np.int64), -1)
        hit = face_all >= 0
        f = face_all[hit]
        nrm = self._normals[f]
        o, d = origins[hit], dirs[hit]
        denom = np.sum(nrm * d, axis=1)
        exact = np.sum(nrm * (self._v0[f] - o), axis=1) / np.where(np.abs(denom) > 1e-12, denom, 1.0)
        # Float64 re-intersection with the reported triangle's plane; keep open3d's t for grazing rays.
        t_hit = np.where(np.abs(denom) > 1e-12, exact, t_all[hit])
        t_all[hit] = t_hit
        points = np.zeros((n, 3))
        points[hit] = o + t_hit[:, None] * d
        normal = np.zeros((n, 3))
        normal[hit] = nrm
        material = np.full(n, BACKGROUND_LABEL, np.int32)
        material[hit] = self.mesh.face_material[f]
        return Hits(hit, t_all, points, face_all, material, normal)

    def occluded(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(N,) bool: does an opaque (non-glass) surface lie along each ray (shadow test)."""
        out = np.zeros(len(origins), bool)
        if self._shadow_scene is None:
            return out
        for s in range(0, len(origins), _CHUNK):
            rays = np.concatenate([origins[s : s + _CHUNK], dirs[s : s + _CHUNK]], axis=1).astype(np.float32)
            out[s : s + _CHUNK] = self._shadow_scene.test_occlusions(o3d.core.Tensor(rays)).numpy()
        return out

    # -- shading ----------------------------------------------------------------------------------
    def radiance(self, origins: np.ndarray, dirs: np.ndarray, depth: int | None = None) -> np.ndarray:
        """Linear RGB radiance (N, 3) float64 arriving along rays (origins, unit dirs), ``depth`` bounces left."""
        depth = self.settings.max_depth if depth is None else depth
        hits = self.cast(origins, dirs)
        out = np.zeros((len(origins), 3))
        miss = ~hits.hit
        out[miss] = self.env.radiance(dirs[miss])
        idx = np.flatnonzero(hits.hit)
        if len(idx) == 0:
            return out
        d = dirs[idx]
        p = hits.points[idx]
        n_geo = hits.normal[idx]
        cos_dn = np.sum(d * n_geo, axis=1)
        n_face = np.where((cos_dn < 0)[:, None], n_geo, -n_geo)  # normal facing the incoming ray
        mats = hits.material[idx]

        direct = self._sun_light(p, n_face)  # (M, 3) irradiance incl. shadows, 0 if facing away
        secondary: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # (target, o, d, weight)
        for mid in np.unique(mats).tolist():
            mat = self.materials[mid]
            sel = np.flatnonzero(mats == mid)
            ps, ns, ds = p[sel], n_face[sel], d[sel]
            if mat.shading is Shading.LAMBERT:
                if mid == TARGET_MATERIAL_ID and self.targets is not None:
                    alb = self.targets.albedo(hits.face[idx[sel]], ps)
                else:
                    alb = self.textures.albedo(mat, ps, ns)
                out[idx[sel]] = alb * (direct[sel] + self.env.ambient_irradiance(ns))
            elif mat.shading is Shading.GLOSSY:
                cos_i = -np.sum(ds * ns, axis=1)
                fres = _schlick(mat.reflectance, cos_i)[:, None]
                alb = self.textures.albedo(mat, ps, ns)
                half = self.env.sun_dir[None, :] - ds
                half /= np.linalg.norm(half, axis=1, keepdims=True)
                spec = np.clip(np.sum(half * ns, axis=1), 0.0, 1.0) ** mat.shininess
                lit = direct[sel] > 0
                highlight = mat.specular * spec[:, None] * np.asarray(self.env.sun_rgb) * lit * 3.0
                out[idx[sel]] = (1 - fres) * alb * (direct[sel] + self.env.ambient_irradiance(ns)) + highlight
                secondary.append((idx[sel], ps + self.eps * ns, _reflect(ds, ns), fres * np.ones((1, 3))))
            elif mat.shading is Shading.MIRROR:
                secondary.append((idx[sel], ps + self.eps * ns, _reflect(ds, ns), np.full((len(sel), 3), mat.specular)))
            else:  # glass
                secondary.extend(self._glass(mat, idx[sel], ps, ns, ds, cos_dn[sel] < 0))
        if secondary:
            target = np.concatenate([s[0] for s in secondary])
            o2 = np.concatenate([s[1] for s in secondary])
            d2 = np.concatenate([s[2] for s in secondary])
            w2 = np.concatenate([s[3] for s in secondary])
            if depth > 0:
                l2 = self.radiance(o2, d2, depth - 1)
            else:
                l2 = self.env.radiance(d2)
            contrib = w2 * l2
            for c in range(3):  # bincount sums in index order: deterministic
                out[:, c] += np.bincount(target, weights=contrib[:, c], minlength=len(out))
        return out

    def _sun_light(self, p: np.ndarray, n_face: np.ndarray) -> np.ndarray:
        sun = self.env.sun_dir
        cos_l = n_face[:, 0] * sun[0] + n_face[:, 1] * sun[1] + n_face[:, 2] * sun[2]
        lit = np.flatnonzero(cos_l > 0)
        irr = np.zeros((len(p), 3))
        if len(lit):
            shadow = self.occluded(p[lit] + self.eps * n_face[lit], np.broadcast_to(sun, (len(lit), 3)))
            irr[lit] = (cos_l[lit] * ~shadow)[:, None] * np.asarray(self.env.sun_rgb)
        return irr

    def _glass(
        self, mat: Material, target: np.ndarray, p: np.ndarray, n: np.ndarray, d: np.ndarray, entering: np.ndarray
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        eta = np.where(entering, 1.0 / mat.ior, mat.ior)
        cos_i = np.clip(-np.sum(d * n, axis=1), 0.0, 1.0)
        sin2_t = eta**2 * (1.0 - cos_i**2)
        tir = sin2_t >= 1.0
        cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, 1.0))
        f0 = ((mat.ior - 1) / (mat.ior + 1)) ** 2
        fres = np.where(tir, 1.0, _schlick(f0, np.where(entering, cos_i, cos_t)))
        refr = eta[:, None] * d + (eta * cos_i - cos_t)[:, None] * n
        refr /= np.maximum(np.linalg.norm(refr, axis=1, keepdims=True), 1e-12)
        tint = np.asarray(mat.albedo)[None, :]
        parts = [(target, p + self.eps * n, _reflect(d, n), np.repeat(fres[:, None], 3, axis=1))]
        ok = ~tir
        if ok.any():
            parts.append((target[ok], p[ok] - self.eps * n[ok], refr[ok], (1 - fres[ok])[:, None] * tint))
        return parts

    # -- views ------------------------------------------------------------------------------------
    def render_view(self, camera: Camera, view: View, rng: np.random.Generator) -> ViewRender:
        """Photo (S×S jittered supersampling), z-depth and labels (pixel centres) of one view."""
        w, h, s = camera.width, camera.height, self.settings.supersample
        rows, cols = np.mgrid[0:h, 0:w]
        centres = np.stack([cols.ravel() + 0.5, rows.ravel() + 0.5], axis=1).astype(np.float64)

        origins, dirs, z_per_t = camera_rays(camera, view, centres)
        hits = self.cast(origins, dirs)
        depth = np.where(hits.hit, hits.t * z_per_t, 0.0).astype(np.float32).reshape(h, w)
        labels = hits.material.astype(np.uint8).reshape(h, w)

        # Stratified jitter: sample (i, j) of a pixel lies in sub-cell (i, j) of its S×S grid.
        acc = np.zeros((h * w, 3))
        for i in range(s):
            for j in range(s):
                jitter = rng.random((h * w, 2))
                px = np.stack([cols.ravel() + (j + jitter[:, 0]) / s, rows.ravel() + (i + jitter[:, 1]) / s], axis=1)
                o, d, _ = camera_rays(camera, view, px)
                acc += self.radiance(o, d)
        image = linear_to_srgb8(acc / (s * s) * self.settings.exposure).reshape(h, w, 3)
        return ViewRender(image, depth, labels)
