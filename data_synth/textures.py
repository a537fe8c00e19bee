"""Procedural albedo textures: functions of the surface point only, so every view sees the same colour.

Patterns are evaluated *triplanarly*: the surface point is projected on the coordinate plane most facing its
normal, which gives undistorted 2D patterns on boxes and planes without UV maps. Noise is lattice value
noise with a seeded permutation table (hand-written: no maintained numpy library evaluates seeded 3D value
noise on arbitrary point arrays, and it is a few lines). The numba kernel is the one used; the numpy
version beside it is the readable reference the tests hold it to (bit-identical results).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from data_synth.materials import Material, Texture


@numba.njit(cache=True)
def _value_noise_kernel(points: np.ndarray, perm: np.ndarray, values: np.ndarray) -> np.ndarray:
    n = points.shape[0]
    out = np.empty(n)
    for k in range(n):
        fx, fy, fz = np.floor(points[k, 0]), np.floor(points[k, 1]), np.floor(points[k, 2])
        ix, iy, iz = np.int64(fx), np.int64(fy), np.int64(fz)
        tx, ty, tz = points[k, 0] - fx, points[k, 1] - fy, points[k, 2] - fz
        ux = tx * tx * (3.0 - 2.0 * tx)
        uy = ty * ty * (3.0 - 2.0 * ty)
        uz = tz * tz * (3.0 - 2.0 * tz)
        acc = 0.0
        # Same corner order and arithmetic as NoiseTable.noise_reference, so results are bit-identical.
        for dx in range(2):
            wx = ux if dx else 1.0 - ux
            for dy in range(2):
                wy = uy if dy else 1.0 - uy
                for dz in range(2):
                    wz = uz if dz else 1.0 - uz
                    h = values[perm[perm[perm[(ix + dx) & 255] + ((iy + dy) & 255)] + ((iz + dz) & 255)]]
                    acc += wx * wy * wz * h
        out[k] = acc
    return out


@dataclass(frozen=True)
class NoiseTable:
    """A seeded lattice for value noise: ``perm`` (512,) int64 (a permutation repeated), ``values`` (256,) float64."""

    seed: int
    perm: np.ndarray = field(init=False, repr=False, compare=False)
    values: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x7E57]))
        p = rng.permutation(256).astype(np.int64)
        object.__setattr__(self, "perm", np.concatenate([p, p]))
        object.__setattr__(self, "values", rng.random(256))

    def hash3(self, i: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Pseudo-random value in [0, 1) per integer lattice point (any int arrays, broadcast), float64."""
        p = self.perm
        return self.values[p[p[p[i & 255] + (j & 255)] + (k & 255)]]

    def noise(self, points: np.ndarray) -> np.ndarray:
        """Smooth value noise in [0, 1] at points (N, 3) float64 (lattice spacing 1), shape (N,)."""
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return _value_noise_kernel(pts, self.perm, self.values)

    def noise_reference(self, points: np.ndarray) -> np.ndarray:
        """Vectorised numpy version of :meth:`noise` (the reference implementation)."""
        base = np.floor(points)
        f = points - base
        i = base.astype(np.int64)
        u = f * f * (3.0 - 2.0 * f)
        out = np.zeros(len(points))
        for dx in (0, 1):
            wx = u[:, 0] if dx else 1.0 - u[:, 0]
            for dy in (0, 1):
                wy = u[:, 1] if dy else 1.0 - u[:, 1]
                for dz in (0, 1):
                    wz = u[:, 2] if dz else 1.0 - u[:, 2]
                    out += wx * wy * wz * self.hash3(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz)
        return out

    def fbm(self, points: np.ndarray, octaves: int = 4, gain: float = 0.5) -> np.ndarray:
        """Fractal sum of ``octaves`` noise layers (frequency doubling), normalised to [0, 1], shape (N,)."""
        total = np.zeros(len(points))
        amp, norm = 1.0, 0.0
        for octave in range(octaves):
            # Offsets decorrelate the octaves' lattices.
            total += amp * self.noise(points * (2.0**octave) + 17.31 * octave)
            norm += amp
            amp *= gain
        return total / norm


def triplanar_coords(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """2D coordinates (a, b) on the coordinate plane most facing each normal, and the axis index (N,) int.

    ``b`` is the vertical (z) coordinate on walls so that brick rows and text lines stay horizontal.
    """
    axis = np.argmax(np.abs(normals), axis=1)
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    a = np.where(axis == 0, y, x)
    b = np.where(axis == 2, y, z)
    return a, b, axis


def _mix(c0: tuple[float, float, float], c1: tuple[float, float, float], t: np.ndarray) -> np.ndarray:
    c0a, c1a = np.asarray(c0), np.asarray(c1)
    return c0a[None, :] * (1.0 - t[:, None]) + c1a[None, :] * t[:, None]


@dataclass(frozen=True)
class TextureField:
    """Albedo of every material at any surface point, for one scene (seed) and pattern scale.

    ``scale`` multiplies each material's ``texture_scale_m`` (presets enlarge patterns for small images).
    """

    seed: int
    scale: float = 1.0
    table: NoiseTable = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "table", NoiseTable(self.seed))

    def albedo(self, mat: Material, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Linear RGB albedo (N, 3) float64 in [0, 1] of ``mat`` at local points (N, 3) with normals (N, 3)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0 or mat.texture is Texture.NONE:
            return np.broadcast_to(np.asarray(mat.albedo, dtype=np.float64), (len(points), 3)).copy()
        s = mat.texture_scale_m * self.scale
        # Each material gets its own region of noise space so equal patterns never repeat across materials.
        p = points / s + 101.7 * (mat.id + 1)
        if mat.texture is Texture.NOISE:
            return self._noise(mat, p)
        a, b, axis = triplanar_coords(p, normals)
        if mat.texture is Texture.BRICKS:
            return self._bricks(mat, p, a, b, axis)
        if mat.texture is Texture.TEXT:
            return self._text(mat, p, a, b, axis)
        return self._wood(mat, p, a, b)

    def _noise(self, mat: Material, p: np.ndarray) -> np.ndarray:
        blotch = np.clip((self.table.fbm(p, octaves=4) - 0.5) * 3.0 + 0.5, 0.0, 1.0)
        speckle = self.table.noise(p * 4.0 + 3.3)
        t = np.clip(0.8 * blotch + 0.4 * (speckle - 0.5), 0.0, 1.0)
        return _mix(mat.albedo2, mat.albedo, t)

    def _bricks(self, mat: Material, p: np.ndarray, a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> np.ndarray:
        row = np.floor(b)
        shifted = a / 2.0 + 0.5 * (row.astype(np.int64) & 1)
        col = np.floor(shifted)
        fa, fb = shifted - col, b - row
        mortar = (fa < 0.04) | (fa > 0.96) | (fb < 0.08) | (fb > 0.92)
        ri, ci = row.astype(np.int64), col.astype(np.int64)
        tone = 0.65 + 0.6 * self.table.hash3(ri, ci, axis)
        grain = 0.85 + 0.3 * self.table.noise(p * 3.0)
        brick = np.asarray(mat.albedo)[None, :] * (tone * grain)[:, None]
        mortar_col = np.asarray(mat.albedo2)[None, :] * (0.9 + 0.2 * self.table.noise(p * 5.0))[:, None]
        return np.clip(np.where(mortar[:, None], mortar_col, brick), 0.0, 1.0)

    def _text(self, mat: Material, p: np.ndarray, a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> np.ndarray:
        # Glyph cells of 1 x 1.5 units on lines of 2 units; each glyph is a random 3x5 bitmap.
        line = np.floor(b / 2.0)
        lb = b / 2.0 - line  # position within the line, 0..1
        cell = np.floor(a)
        la = a - cell
        li, ci = line.astype(np.int64), cell.astype(np.int64)
        in_glyph = (lb > 0.15) & (lb < 0.9) & (la > 0.12) & (la < 0.88)
        is_space = self.table.hash3(li, ci, axis + 7) < 0.18
        gx = np.clip(((la - 0.12) / 0.76 * 3).astype(np.int64), 0, 2)
        gy = np.clip(((lb - 0.15) / 0.75 * 5).astype(np.int64), 0, 4)
        bit = self.table.hash3(li * 8 + gy, ci * 4 + gx, axis + 31) < 0.5
        ink = in_glyph & ~is_space & bit
        paper = np.asarray(mat.albedo)[None, :] * (0.9 + 0.15 * self.table.noise(p * 2.0))[:, None]
        return np.clip(np.where(ink[:, None], np.asarray(mat.albedo2)[None, :], paper), 0.0, 1.0)

    def _wood(self, mat: Material, p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        warp = self.table.fbm(p * 0.25, octaves=3)
        rings = 0.5 + 0.5 * np.sin(2 * np.pi * (a * 0.7 + 3.0 * warp))
        grain = self.table.noise(p * np.array([0.5, 6.0, 6.0]))  # streaks along x
        speckle = self.table.noise(p * 3.0 + 7.7)  # pores: fine detail for feature matching
        t = 0.5 * rings + 0.6 * (grain - 0.35) + 0.5 * (speckle - 0.5)
        return np.clip(_mix(mat.albedo2, mat.albedo, np.clip(t, 0, 1)), 0.0, 1.0)
