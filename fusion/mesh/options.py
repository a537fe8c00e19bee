"""Options of the meshing pipeline (:mod:`fusion.mesh.pipeline` and its steps), without their heavy imports.

Kept apart from the meshing modules (numba, scipy, open3d) so that the pipeline's configuration and the command line
can name and check them without loading those; each step's module re-exports its own options.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from core.errors import ConfigError
from fusion.mesh.types import as_choice


class NormalFallback(str, Enum):
    """What to do with Gaussians that have no usable shortest axis (near-isotropic)."""

    ESTIMATE = "estimate"  # PCA of the neighbouring centres, then orientation
    ERROR = "error"  # refuse the set (DataError)
    DROP = "drop"  # leave those Gaussians out


@dataclass(frozen=True)
class OrientedPointOptions:
    """Options of :func:`oriented_points_from_gaussians` (see the module docstring).

    min_opacity: Gaussians with α below are ignored (default 0.02: faint floaters).
    full_weight_opacity: α from which a Gaussian counts fully (default 0.5); fainter ones are sampled less.
    sample_spacing: reference spacing s in metres (None: the median √(σ_a σ_b)).
    footprint_sigmas: radius of a Gaussian's sampled ellipse in σ (default 1.5).
    max_samples_per_gaussian: cap of points per Gaussian (default 256).
    isotropy_ratio: σ_min / σ_mid above which the shortest axis is no normal (default 0.8).
    normal_fallback: see :class:`NormalFallback` (default estimate).
    normal_neighbors: neighbours for PCA normals and for orienting by trusted normals (default 16).
    seed: seed of the sampling.
    """

    min_opacity: float = 0.02
    full_weight_opacity: float = 0.5
    sample_spacing: float | None = None
    footprint_sigmas: float = 1.5
    max_samples_per_gaussian: int = 256
    isotropy_ratio: float = 0.8
    normal_fallback: NormalFallback = NormalFallback.ESTIMATE
    normal_neighbors: int = 16
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_opacity < 1.0:
            raise ConfigError(f"min_opacity must lie in [0, 1), got {self.min_opacity}")
        if not 0.0 < self.full_weight_opacity <= 1.0:
            raise ConfigError(f"full_weight_opacity must lie in (0, 1], got {self.full_weight_opacity}")
        if self.sample_spacing is not None and not (np.isfinite(self.sample_spacing) and self.sample_spacing > 0):
            raise ConfigError(f"sample_spacing must be a positive distance in metres, got {self.sample_spacing}")
        if not (np.isfinite(self.footprint_sigmas) and self.footprint_sigmas > 0):
            raise ConfigError(f"footprint_sigmas must be positive, got {self.footprint_sigmas}")
        if self.max_samples_per_gaussian < 1:
            raise ConfigError(f"max_samples_per_gaussian must be >= 1, got {self.max_samples_per_gaussian}")
        if not 0.0 < self.isotropy_ratio <= 1.0:
            raise ConfigError(f"isotropy_ratio must lie in (0, 1], got {self.isotropy_ratio}")
        if self.normal_neighbors < 3:
            raise ConfigError(f"normal_neighbors must be >= 3, got {self.normal_neighbors}")
        object.__setattr__(self, "normal_fallback", as_choice(NormalFallback, self.normal_fallback, "normal_fallback"))


@dataclass(frozen=True)
class PoissonOptions:
    """Options of :func:`poisson_reconstruct` and :func:`trim_mesh`.

    depth: octree depth (None: from the sampling, see the module docstring). cell_factor: finest cell in units of
    the median point spacing (default 1.5). min_depth / max_depth: clamp of the automatic depth (5 / 10).
    scale: Poisson bounding cube / sample bounding cube (open3d's default 1.1). linear_fit: open3d's option.
    point_weight: screening weight (open3d default 2; 0 is unscreened Poisson). close: cap the untrimmed mesh on the
    faces of the reconstruction cube where the surface runs into it, so that it is watertight (default True; the caps
    never survive trimming). manifold: remove the pillows and flat tetrahedra PoissonRecon emits and split its other
    non-manifold edges (:mod:`fusion.mesh.manifold`), so that the untrimmed mesh is edge-manifold (default True).
    footprint_support: a vertex within the footprint (``OrientedPoints.footprint``) of any
    point is supported too, whatever ``support_factor`` says (default False).
    density_quantile: vertices below
    this quantile of the densities are trimmed (default 0: off, see the module docstring). support_factor:
    vertices farther than this many spacings from their nearest point are trimmed (default 2; None: off).
    support_neighbors: neighbours over which a point's local spacing is taken (default 8).
    min_component_fraction: pieces with fewer triangles than this share of the trimmed mesh are dropped (default
    0.01). threads: open3d threads (default 1: deterministic; -1 uses all cores, faster, but the order of its
    float reductions varies from run to run, vertices move by ~1e-7 m and decimation can turn that into a different
    triangulation).
    """

    depth: int | None = None
    cell_factor: float = 1.5
    min_depth: int = 5
    max_depth: int = 10
    scale: float = 1.1
    linear_fit: bool = False
    point_weight: float = 2.0
    close: bool = True
    manifold: bool = True
    footprint_support: bool = False
    density_quantile: float = 0.0
    support_factor: float | None = 2.0
    support_neighbors: int = 8
    min_component_fraction: float = 0.01
    threads: int = 1

    def __post_init__(self) -> None:
        if self.depth is not None and not 2 <= self.depth <= 14:
            raise ConfigError(f"Poisson depth must lie in 2..14, got {self.depth}")
        if not 2 <= self.min_depth <= self.max_depth <= 14:
            raise ConfigError(f"need 2 <= min_depth <= max_depth <= 14, got {self.min_depth}, {self.max_depth}")
        if not (np.isfinite(self.cell_factor) and self.cell_factor > 0):
            raise ConfigError(f"cell_factor must be positive, got {self.cell_factor}")
        if not self.scale >= 1.0:
            raise ConfigError(f"scale must be >= 1, got {self.scale}")
        if not self.point_weight >= 0:
            raise ConfigError(f"point_weight must be >= 0, got {self.point_weight}")
        if not 0.0 <= self.density_quantile < 1.0:
            raise ConfigError(f"density_quantile must lie in [0, 1), got {self.density_quantile}")
        if self.support_factor is not None and not (np.isfinite(self.support_factor) and self.support_factor > 0):
            raise ConfigError(f"support_factor must be positive (or None), got {self.support_factor}")
        if self.support_neighbors < 1:
            raise ConfigError(f"support_neighbors must be >= 1, got {self.support_neighbors}")
        if not 0.0 <= self.min_component_fraction < 1.0:
            raise ConfigError(f"min_component_fraction must lie in [0, 1), got {self.min_component_fraction}")


class Decimator(str, Enum):
    AUTO = "auto"  # fast-simplification, then open3d if the count is still outside the tolerance
    FAST_SIMPLIFICATION = "fast-simplification"
    OPEN3D = "open3d"


@dataclass(frozen=True)
class DecimateOptions:
    """method: which decimator (default auto, see the module docstring). tolerance: allowed |count − budget| / budget
    (default 0.01). max_attempts: runs with a corrected target, per decimator (default 6). aggressiveness:
    fast-simplification's ``agg`` (default 7, its own)."""

    method: Decimator = Decimator.AUTO
    tolerance: float = 0.01
    max_attempts: int = 6
    aggressiveness: float = 7.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "method", as_choice(Decimator, self.method, "decimation method"))
        if not 0.0 <= self.tolerance < 1.0:
            raise ConfigError(f"tolerance must lie in [0, 1), got {self.tolerance}")
        if self.max_attempts < 1:
            raise ConfigError(f"max_attempts must be >= 1, got {self.max_attempts}")


@dataclass(frozen=True)
class SnapshotOptions:
    """region_radius: metres (None: 4 × the median nearest-neighbour distance between the merged set's splats).
    min_opacity: snapshot Gaussians with α below this before raising are ignored (default 0.005, the pruning cut of
    3DGS densification: such Gaussians are about to be removed by training)."""

    region_radius: float | None = None
    min_opacity: float = 0.005

    def __post_init__(self) -> None:
        if self.region_radius is not None and not (np.isfinite(self.region_radius) and self.region_radius > 0):
            raise ConfigError(f"region_radius must be a positive distance in metres, got {self.region_radius}")
        if not 0.0 <= self.min_opacity < 1.0:
            raise ConfigError(f"min_opacity must lie in [0, 1), got {self.min_opacity}")


class MeshSource(str, Enum):
    """What is meshed: all Gaussians of the merged set (hybrid, their ellipses sampled), only those converted from
    MVS, or the survey point product (MVS points and trustworthy splat centres; see
    :mod:`fusion.mesh.survey_points`)."""

    ALL = "all"
    MVS = "mvs"
    SURVEY = "survey"


@dataclass(frozen=True)
class MeshOptions:
    """budget: triangles of the result (None: no decimation). source: see :class:`MeshSource` (default all).
    use_snapshots: add the snapshot union for splat regions when snapshots are given (default True; not for
    source mvs).
    mvs_priority: splat points (trained or snapshot) closer to an MVS point than this many median MVS point
    spacings are left out (default 2; 0 keeps all): where MVS measured the surface, its metric points alone shape
    it, and splats fill only where MVS has none (splats float around surfaces by a fraction of their σ).
    color_neighbors: Gaussians blended per vertex colour (default 8). surface_only: leave Gaussians whose
    ``surface`` field is 0 out of the geometry (default True; no effect on a set without that field; colours still
    come from every Gaussian). Sub-options: see their classes."""

    budget: int | None = 10_000
    source: MeshSource = MeshSource.ALL
    use_snapshots: bool = True
    mvs_priority: float = 2.0
    color_neighbors: int = 8
    surface_only: bool = True
    points: OrientedPointOptions = field(default_factory=OrientedPointOptions)
    poisson: PoissonOptions = field(default_factory=PoissonOptions)
    decimate: DecimateOptions = field(default_factory=DecimateOptions)
    snapshots: SnapshotOptions = field(default_factory=SnapshotOptions)

    def __post_init__(self) -> None:
        object.__setattr__(self, "source", as_choice(MeshSource, self.source, "mesh source"))
        b = self.budget
        if b is not None and (isinstance(b, bool) or not isinstance(b, (int, np.integer)) or b < 1):
            raise ConfigError(f"the triangle budget must be a positive integer (or None for no decimation), got {b!r}")
        if not (np.isfinite(self.mvs_priority) and self.mvs_priority >= 0):
            raise ConfigError(f"mvs_priority must be >= 0 (spacings), got {self.mvs_priority}")
        if self.color_neighbors < 1:
            raise ConfigError(f"color_neighbors must be >= 1, got {self.color_neighbors}")
