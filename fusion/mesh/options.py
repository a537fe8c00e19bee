"""Options of the meshing pipeline (:mod:`fusion.mesh.pipeline` and its steps), without their heavy imports.

Kept apart from the meshing modules (numba, scipy, open3d) so that the pipeline's configuration and the command line
can name and check them without loading those; each step's module re-exports its own options.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

from core.constraints import Choice, Constrained, Constraints, Interval, NoneOr
from core.errors import ConfigError


class NormalFallback(str, Enum):
    """What to do with Gaussians that have no usable shortest axis (near-isotropic)."""

    ESTIMATE = "estimate"  # PCA of the neighbouring centres, then orientation
    ERROR = "error"  # refuse the set (DataError)
    DROP = "drop"  # leave those Gaussians out


@dataclass(frozen=True)
class OrientedPointOptions(Constrained):
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

    constraints: ClassVar[Constraints] = {
        "min_opacity": Interval(float, 0, 1, closed="left"),
        "full_weight_opacity": Interval(float, 0, 1, closed="right"),
        "sample_spacing": NoneOr(Interval(float, 0, None, closed="neither")),
        "footprint_sigmas": Interval(float, 0, None, closed="neither"),
        "max_samples_per_gaussian": Interval(int, 1, None),
        "isotropy_ratio": Interval(float, 0, 1, closed="right"),
        "normal_fallback": Choice(NormalFallback),
        "normal_neighbors": Interval(int, 3, None),
    }


@dataclass(frozen=True)
class PoissonOptions(Constrained):
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

    constraints: ClassVar[Constraints] = {
        "depth": NoneOr(Interval(int, 2, 14)),
        "cell_factor": Interval(float, 0, None, closed="neither"),
        "min_depth": Interval(int, 2, 14),
        "max_depth": Interval(int, 2, 14),
        "scale": Interval(float, 1, None),
        "point_weight": Interval(float, 0, None),
        "density_quantile": Interval(float, 0, 1, closed="left"),
        "support_factor": NoneOr(Interval(float, 0, None, closed="neither")),
        "support_neighbors": Interval(int, 1, None),
        "min_component_fraction": Interval(float, 0, 1, closed="left"),
    }

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.min_depth > self.max_depth:
            raise ConfigError(f"min_depth must be <= max_depth, got {self.min_depth} > {self.max_depth}")


class Decimator(str, Enum):
    AUTO = "auto"  # fast-simplification, then open3d if the count is still outside the tolerance
    FAST_SIMPLIFICATION = "fast-simplification"
    OPEN3D = "open3d"


@dataclass(frozen=True)
class DecimateOptions(Constrained):
    """method: which decimator (default auto, see the module docstring). tolerance: allowed |count − budget| / budget
    (default 0.01). max_attempts: runs with a corrected target, per decimator (default 6). aggressiveness:
    fast-simplification's ``agg`` (default 7, its own)."""

    method: Decimator = Decimator.AUTO
    tolerance: float = 0.01
    max_attempts: int = 6
    aggressiveness: float = 7.0

    constraints: ClassVar[Constraints] = {
        "method": Choice(Decimator),
        "tolerance": Interval(float, 0, 1, closed="left"),
        "max_attempts": Interval(int, 1, None),
    }


@dataclass(frozen=True)
class SnapshotOptions(Constrained):
    """region_radius: metres (None: 4 × the median nearest-neighbour distance between the merged set's splats).
    min_opacity: snapshot Gaussians with α below this before raising are ignored (default 0.005, the pruning cut of
    3DGS densification: such Gaussians are about to be removed by training)."""

    region_radius: float | None = None
    min_opacity: float = 0.005

    constraints: ClassVar[Constraints] = {
        "region_radius": NoneOr(Interval(float, 0, None, closed="neither")),
        "min_opacity": Interval(float, 0, 1, closed="left"),
    }


class MeshSource(str, Enum):
    """What is meshed: all Gaussians of the merged set (hybrid, their ellipses sampled), only those converted from
    MVS, or the survey point product (MVS points and trustworthy splat centres; see
    :mod:`fusion.mesh.survey_points`)."""

    ALL = "all"
    MVS = "mvs"
    SURVEY = "survey"


@dataclass(frozen=True)
class MeshOptions(Constrained):
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

    constraints: ClassVar[Constraints] = {
        "budget": NoneOr(Interval(int, 1, None)),
        "source": Choice(MeshSource),
        "mvs_priority": Interval(float, 0, None),
        "color_neighbors": Interval(int, 1, None),
    }
