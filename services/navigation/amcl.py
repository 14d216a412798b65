"""Localisation on a known occupancy map: an AMCL-style particle filter (paper Section 5.2
uses ROS's ``amcl``; this is the same algorithm family, written for numpy).

Thrun, Burgard, Fox, *Probabilistic Robotics* (PR) names the pieces:

- motion: ``sample_motion_model_odometry`` (PR Table 5.6) in its omnidirectional form (as
  AMCL's ``omni`` model): a quadruped walks forward, sideways and turns, so the odometry
  increment is split into a translation along its own direction, a strafe across it and a
  rotation, each with noise whose variance grows with translation and rotation;
- measurement: ``likelihood_field_range_finder_model`` (PR Table 6.3) over a subsample of
  the beams, summed in log space so hundreds of particles x beams never underflow;
- resampling: ``low_variance_sampler`` (PR Table 4.4), only when the effective sample size
  drops (adaptive resampling), with the new particle count from ``KLD_Sampling_MCL``
  (PR Table 8.4) and random particles injected by ``Augmented_MCL`` (PR Table 8.3) when
  the short-term average likelihood falls below the long-term one (kidnapping, a bad
  initial pose);
- estimate: the weighted mean of the heaviest cluster of particles (AMCL's ``pf_cluster``),
  not of all of them, which matters while several hypotheses survive (global localisation
  in a house of two similar rooms);
- a final fine correction: once the filter has converged, a few Gauss-Newton steps align
  the full scan with the map's distance field (Hector/Cartographer-style), which takes the
  estimate below the particle spread and the grid's cell size. The particles themselves are
  never moved by it: it refines the output, the filter stays a filter.

The filter integrates motion only when the robot has moved ``update_min_d`` or turned
``update_min_a`` since the last filter step (as AMCL): many tiny noisy motion steps would
under-diffuse the particles, and weighing the same view again and again would make the
filter overconfident. Between filter steps the estimate follows the odometry.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from quadmanip.services.navigation.distance_field import DistanceField
from quadmanip.services.navigation.grid import GridGeometry, Pose2, compose, invert, wrap
from quadmanip.services.navigation.scan import ScanPoints
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["AmclConfig", "FilterStats", "ParticleFilter", "kld_sample_count"]


@dataclass(frozen=True)
class AmclConfig:
    """Tunables of the filter (ROS amcl's parameter names where one exists)."""

    min_particles: int = 200
    max_particles: int = 3000
    """Upper bound of the KLD count; ``initialize`` starts with it."""
    global_particles: int = 20000
    """Particles ``initialize_global`` spreads over the map (KLD cuts them to at most
    max_particles at the first resampling)."""
    kld_epsilon: float = 0.02
    """KLD bound between the sample-based and the true posterior (amcl ``kld_err``)."""
    kld_z: float = 2.326
    """Upper standard-normal quantile of 1 - delta (2.326: delta = 0.01; amcl ``kld_z``)."""
    kld_bin: tuple[float, float, float] = (0.5, 0.5, math.radians(10.0))
    """Histogram bin (x m, y m, yaw rad) whose occupied count drives KLD sampling."""
    # odometry noise, variance factors (PR Table 5.6's alpha, amcl's omni model's order):
    odom_alpha1: float = 0.05
    """rotation variance per rotation^2"""
    odom_alpha2: float = 0.02
    """rotation variance per translation^2"""
    odom_alpha3: float = 0.02
    """translation variance per translation^2"""
    odom_alpha4: float = 0.005
    """translation and strafe variance per rotation^2"""
    odom_alpha5: float = 0.02
    """strafe variance per translation^2"""
    update_min_d: float = 0.1
    """Metres moved before the filter integrates motion and weighs a scan."""
    update_min_a: float = math.radians(10.0)
    """Radians turned before the filter integrates motion and weighs a scan."""
    resample_ess_ratio: float = 0.5
    """Resample when the effective sample size drops below this fraction of the count."""
    # likelihood field (PR Table 6.3):
    sigma_hit: float = 0.05
    """Std (m) of a hit about the nearest obstacle, once the filter has converged."""
    sigma_hit_wide: float = 0.2
    """Std (m) used while the filter has not converged: a sparse particle set has no
    particle within a few centimetres of the truth, so the narrow model would be flat
    everywhere but on lucky wrong hypotheses (annealing, coarse to fine)."""
    likelihood_exponent: float = 1.0
    """Power on the scan likelihood (tempering): beams are not independent (neighbours see
    the same wall, the map has errors), and a full product makes the filter overconfident."""
    global_exponent: float = 0.1
    """The tempering while a global localisation has not settled (the first
    ``global_weighings`` scans after :meth:`ParticleFilter.initialize_global`)."""
    global_weighings: int = 10
    """Scans weighed (each after ``update_min_d`` / ``update_min_a`` of motion) before a
    global localisation may call itself converged. *Measured* on the committed map with
    the recorded walk: at full weight the first scan alone put all the mass on one
    cluster, and from 2 of 4 starts it was the wrong room's (3.6 and 2.3 m off), which
    the set, already cut to 200 particles, never left. Two rooms of one house look alike
    from one place; a metre of walking tells them apart."""
    z_hit: float = 0.95
    z_rand: float = 0.05
    max_beams: int = 60
    laser_likelihood_max_dist: float = 2.0
    """Distance field cap (m): beyond it a hit is as likely as a random reading."""
    occupied_threshold: int = 65
    free_threshold: int = 25
    surface_offset: float | None = 0.0
    """Where the obstacle surface lies, as a distance from occupied cell centres; None:
    half a cell (a range ends where the beam enters the occupied cell, as on a raster
    drawn from the true geometry). 0 for maps built by :mod:`.slam`: there a hit weighs
    more than a pass, so range noise grows walls by a cell toward the robot and the
    surface lies at the first occupied cells' centres. On the committed house map and a
    recorded walk: 1.3-2.3 cm RMS with 0, 4.1-4.3 cm with half a cell."""
    # recovery (PR Table 8.3):
    recovery_alpha_slow: float = 0.001
    recovery_alpha_fast: float = 0.1
    recovery_sigma: float = 0.2
    """Std (m) of the fixed model whose average likelihood drives random injection, so
    the statistic does not jump when the weighing model narrows at convergence."""
    # convergence and estimate:
    cluster_bin: tuple[float, float, float] = (0.25, 0.25, math.radians(15.0))
    """Histogram bin that groups particles into hypotheses (connected occupied bins)."""
    converged_std_xy: float = 0.12
    converged_std_yaw: float = math.radians(8.0)
    converged_mass: float = 0.85
    """Weight fraction the best cluster needs to count as *the* estimate."""
    # fine correction (Gauss-Newton of the scan against the distance field):
    refine: bool = True
    refine_iterations: int = 8
    refine_max_beams: int = 120
    refine_inlier_distance: float = 0.25
    """Points farther than this from the map after alignment are outliers (people,
    objects not on the map) and do not pull."""
    refine_huber: float = 0.05
    refine_max_shift: tuple[float, float] = (0.15, math.radians(6.0))
    """A correction larger than this (m, rad) from the particle estimate is rejected."""
    refine_min_inliers: float = 0.5
    """Fraction of the scan that must fit the map for a correction to be trusted."""
    refine_surface_offset: float = 0.0
    """Distance (m) from a cell centre of the fine surface raster (``surface``) to the
    surface it stands for: 0 for the mapping's raster of returns (each cell holds returns
    off the surface itself)."""
    pose_penalty: float = 10.0
    """Log-weight taken from a particle standing on an occupied, unknown or off-map cell."""
    # pose hints (``navigation/initial_pose``, :meth:`ParticleFilter.hint`):
    hint_agree_xy: float = 0.3
    """A converged estimate within this distance (m) of a pose hint is kept."""
    hint_agree_yaw: float = math.radians(15.0)
    """... and within this angle (rad) of the hint's heading."""


def kld_sample_count(k: np.ndarray | int, epsilon: float, z: float) -> np.ndarray:
    """Particles needed so that, with probability 1 - delta, the KL divergence between
    the sample-based and the true posterior stays below ``epsilon`` when the samples
    occupy ``k`` histogram bins (Fox 2003; PR Table 8.4, Wilson-Hilferty chi-square)."""
    k1 = np.maximum(np.asarray(k, dtype=float) - 1.0, 1.0)
    a = 2.0 / (9.0 * k1)
    n = k1 / (2.0 * epsilon) * (1.0 - a + np.sqrt(a) * z) ** 3
    return np.where(np.asarray(k) <= 1, 1.0, n)


@dataclass
class _Estimate:
    pose: Pose2
    cov: np.ndarray
    odom: Pose2 | None
    """The odometry pose the particles stood at when this was computed."""
    mass: float = 1.0
    converged: bool = False
    clusters: int = 1


@dataclass
class _Refined:
    pose: Pose2
    odom: Pose2 | None
    inliers: float = 0.0
    iterations: int = 0


@dataclass
class FilterStats:
    """What the last ``update`` did, for logs and tests."""

    weighed: int = 0
    resampled: int = 0
    injected: int = 0
    refined: int = 0
    last_injection_probability: float = 0.0


class ParticleFilter:
    """Monte Carlo localisation on an occupancy grid (-1 unknown, 0..100 occupancy)."""

    def __init__(
        self,
        config: AmclConfig,
        occupancy: np.ndarray,
        geometry: GridGeometry,
        rng: np.random.Generator | None = None,
        surface: tuple[np.ndarray, GridGeometry] | None = None,
    ) -> None:
        """``surface``: optionally the map's fine raster of surfaces (True where the
        mapping saw returns, on its own finer grid; ``map_io.load_surface``). The final
        correction then aligns the scan with it instead of with the 5 cm grid, whose
        cells place a wall anywhere within 2.5 cm (docs/navigation.md)."""
        occupancy = np.asarray(occupancy)
        if occupancy.shape != geometry.shape:
            raise ValueError(f"occupancy shape {occupancy.shape} != grid {geometry.shape}")
        self.config = config
        self.geometry = geometry
        self.rng = rng if rng is not None else np.random.default_rng()
        occ = occupancy.astype(np.int16)
        self._occupied = occ >= config.occupied_threshold
        unknown = occ < 0
        free = (occ >= 0) & (occ <= config.free_threshold)
        self._free_cells = np.flatnonzero(free)
        if len(self._free_cells) == 0:
            raise ValueError("the map has no free cell")
        self.field = DistanceField(self._occupied, geometry, config.laser_likelihood_max_dist)
        self._surface = (
            0.5 * geometry.resolution if config.surface_offset is None else config.surface_offset
        )
        # the field the final correction aligns the scan with, and its surface offset
        self._refine_field, self._refine_surface = self.field, self._surface
        if surface is not None:
            mask, sgeo = np.asarray(surface[0], dtype=bool), surface[1]
            if mask.shape != sgeo.shape:
                raise ValueError(f"surface shape {mask.shape} != its grid {sgeo.shape}")
            if not mask.any():
                raise ValueError("the surface raster marks no surface")
            self._refine_field = DistanceField(mask, sgeo, config.laser_likelihood_max_dist)
            self._refine_surface = config.refine_surface_offset
        # the distance a hit is scored with: from the obstacle surface; an unknown cell
        # reads "nothing known here" (the cap: a random reading) unless it is the far face
        # of a wall within two sigmas, where a slightly long range can legitimately end
        d = np.maximum(self.field.distance_grid - self._surface, 0.0)
        cap = config.laser_likelihood_max_dist
        d[unknown & (d > 2.0 * config.sigma_hit)] = cap
        pad = np.full((geometry.height + 2, geometry.width + 2), cap)  # off the map: cap
        pad[1:-1, 1:-1] = d
        self._dgrid = pad
        # where a robot can stand: known free (or occupied < threshold) cells
        stand = np.zeros((geometry.height + 2, geometry.width + 2), dtype=bool)
        stand[1:-1, 1:-1] = ~self._occupied & ~unknown
        self._stand = stand
        self.stats = FilterStats()
        self.particles = np.zeros((0, 3))
        self.log_weights = np.zeros(0)
        self._odom_latest: Pose2 | None = None
        self._odom_applied: Pose2 | None = None
        self._pending = False
        self._force_update = False
        self._w_slow = 0.0
        self._global_left = 0  # weighings left before a global start may converge
        self._w_fast = 0.0
        self._estimate: _Estimate | None = None
        self._refined: _Refined | None = None
        self._ignored = np.zeros((0, 4))  # (x0, y0, x1, y1) map areas whose returns are dropped

    def ignore_areas(self, areas: Sequence[tuple[float, float, float, float]]) -> None:
        """Drop the scan's returns that fall (at the estimate) within ``areas`` (x_min,
        y_min, x_max, y_max; map): scenery that moves, as a drawer's front, which the map
        shows where it was when mapped. Before the filter has an estimate every return
        counts."""
        a = np.asarray(list(areas), dtype=float).reshape(-1, 4)
        if np.any(a[:, 2] <= a[:, 0]) or np.any(a[:, 3] <= a[:, 1]):
            raise ValueError(f"ignored areas must have x_min < x_max, y_min < y_max: {a}")
        self._ignored = a

    def _in_ignored(self, pts: np.ndarray) -> np.ndarray:
        """Mask of the base-frame ``pts`` that lie, seen from the estimate, in an ignored
        area."""
        if not len(self._ignored) or self._estimate is None:
            return np.zeros(len(pts), dtype=bool)
        x, y, yaw = self._particle_pose()
        c, s = math.cos(yaw), math.sin(yaw)
        wx = x + c * pts[:, 0] - s * pts[:, 1]
        wy = y + s * pts[:, 0] + c * pts[:, 1]
        a = self._ignored
        inside = (
            (wx[:, None] >= a[None, :, 0])
            & (wx[:, None] <= a[None, :, 2])
            & (wy[:, None] >= a[None, :, 1])
            & (wy[:, None] <= a[None, :, 3])
        )
        return inside.any(axis=1)

    # ------------------------------------------------------------------ initialisation

    def initialize(self, pose: Pose2, std: tuple[float, float, float] = (0.25, 0.25, 0.2)) -> None:
        """Particles from a Gaussian about a given pose (an operator's "2D pose estimate"):
        the std should cover the doubt, KLD sampling shrinks the set once it has converged."""
        n = self.config.max_particles
        p = np.empty((n, 3))
        p[:, 0] = pose[0] + self.rng.normal(0.0, std[0], n)
        p[:, 1] = pose[1] + self.rng.normal(0.0, std[1], n)
        p[:, 2] = wrap(pose[2] + self.rng.normal(0.0, std[2], n))
        self._reset(p)

    def initialize_global(self) -> None:
        """Particles spread uniformly over the map's free space and all headings (global
        localisation: the robot does not know where it is)."""
        self._reset(self._random_particles(self.config.global_particles))
        self._global_left = self.config.global_weighings

    def hint(
        self,
        pose: Pose2,
        std: tuple[float, float, float],
        odom_pose: Pose2 | None = None,
    ) -> str:
        """An outside belief of where the robot is (a pose hint: an operator's "2D pose
        estimate", or the behavior service telling a restarted navigation where the robot
        was). Returns what was done: ``"initialized"`` (particles drawn about ``pose`` with
        ``std``) or ``"kept"`` (the estimate stays; the hint is ignored).

        The filter re-initialises only when it has not converged, or when its converged
        estimate is farther from the hint than ``hint_agree_xy`` / ``hint_agree_yaw``:

        - not converged: the hint narrows a search that has not settled, which is what it
          is for (a global start, or a start pose far from where the robot stands);
        - converged and near the hint: the filter has weighed scans on the map since it
          converged, so its estimate is better than a hint that may be a moment old or
          carried by drifting odometry; re-drawing the particles would only widen the
          pose again for a few scans (a restarted navigation that happens to start where
          the robot is must not be disturbed);
        - converged far from the hint: a filter converges on its *prior* as easily as on
          the truth. A restarted navigation draws its particles about the configured start
          pose with a spread already below the convergence bound, so it reports
          ``localized`` at the start pose at once, and scans can take long to pull a tight
          wrong cluster away (Augmented MCL injects only once the fit degrades). A strong
          disagreement therefore means the prior was wrong, and the hint wins.

        ``odom_pose`` is the odometry pose the hint refers to (the newest one): the
        particles then stand at that odometry, so the next :meth:`predict` moves them by
        the motion since the hint, not since the last filter step.
        """
        pose = (float(pose[0]), float(pose[1]), float(wrap(pose[2])))
        est = self._estimate
        if est is not None and est.converged and len(self.particles):
            here, _ = self.estimate()
            dxy = math.hypot(here[0] - pose[0], here[1] - pose[1])
            dyaw = abs(float(wrap(here[2] - pose[2])))
            if dxy <= self.config.hint_agree_xy and dyaw <= self.config.hint_agree_yaw:
                return "kept"
        if odom_pose is not None:
            self._odom_latest = (float(odom_pose[0]), float(odom_pose[1]), float(odom_pose[2]))
        self.initialize(pose, std)
        return "initialized"

    def _reset(self, particles: np.ndarray) -> None:
        self.particles = particles
        self.log_weights = np.full(len(particles), -math.log(len(particles)))
        self._odom_applied = self._odom_latest
        self._pending = False
        self._force_update = True
        self._w_slow = self._w_fast = 0.0
        self._refined = None
        self._global_left = 0
        self._estimate = self._cluster_estimate(self._odom_applied)

    def _random_particles(self, n: int) -> np.ndarray:
        g = self.geometry
        cells = self.rng.choice(self._free_cells, size=n)
        rows, cols = np.divmod(cells, g.width)
        p = np.empty((n, 3))
        p[:, 0] = g.origin_x + (cols + self.rng.random(n)) * g.resolution
        p[:, 1] = g.origin_y + (rows + self.rng.random(n)) * g.resolution
        p[:, 2] = self.rng.uniform(-math.pi, math.pi, n)
        return p

    # ------------------------------------------------------------------ motion

    def predict(self, odom_pose: Pose2) -> None:
        """Move the particles by the odometry increment since the last filter step, once
        it is large enough (PR Table 5.6, omnidirectional); the first call only stores."""
        odom_pose = (float(odom_pose[0]), float(odom_pose[1]), float(odom_pose[2]))
        self._odom_latest = odom_pose
        if self._odom_applied is None:
            self._odom_applied = odom_pose
            if self._estimate is not None and self._estimate.odom is None:
                self._estimate.odom = odom_pose
            return
        delta = compose(invert(self._odom_applied), odom_pose)
        trans = math.hypot(delta[0], delta[1])
        if trans < self.config.update_min_d and abs(delta[2]) < self.config.update_min_a:
            return
        self._sample_motion(delta)
        self._odom_applied = odom_pose
        self._pending = True

    def rebase(self, odom_pose: Pose2) -> None:
        """The odometry goes on in a new frame from ``odom_pose`` (its source restarted:
        a new locomotion process counts from its own origin) while the robot stood where
        the last odometry left it. The particles and the estimate stay where they are in
        the map; increments count from ``odom_pose``. Without this the jump between the
        two frames was taken for motion, and the robot was lost after every restart of
        locomotion."""
        new = (float(odom_pose[0]), float(odom_pose[1]), float(odom_pose[2]))
        old = self._odom_latest
        if old is not None and self._odom_applied is not None:
            delta = compose(invert(self._odom_applied), old)
            if any(abs(d) > 0.0 for d in delta):  # motion not yet given to the particles
                self._sample_motion(delta)
        if self._estimate is not None:
            self._estimate.pose = _follow(self._estimate.pose, self._estimate.odom, old)
            self._estimate.odom = new
        if self._refined is not None:
            r = self._refined
            self._refined = _Refined(_follow(r.pose, r.odom, old), new, r.inliers, r.iterations)
        self._odom_applied = self._odom_latest = new

    def _sample_motion(self, delta: Pose2) -> None:
        c = self.config
        n = len(self.particles)
        dx, dy, dth = delta
        trans = math.hypot(dx, dy)
        rot = abs(dth)
        sd_rot = math.sqrt(c.odom_alpha1 * rot**2 + c.odom_alpha2 * trans**2)
        sd_along = math.sqrt(c.odom_alpha3 * trans**2 + c.odom_alpha4 * rot**2)
        sd_strafe = math.sqrt(c.odom_alpha5 * trans**2 + c.odom_alpha4 * rot**2)
        ux, uy = (dx / trans, dy / trans) if trans > 1e-9 else (1.0, 0.0)
        n_along = self.rng.normal(0.0, sd_along, n) if sd_along > 0 else np.zeros(n)
        n_strafe = self.rng.normal(0.0, sd_strafe, n) if sd_strafe > 0 else np.zeros(n)
        n_rot = self.rng.normal(0.0, sd_rot, n) if sd_rot > 0 else np.zeros(n)
        bx = dx + n_along * ux - n_strafe * uy  # noisy increment in each particle's frame
        by = dy + n_along * uy + n_strafe * ux
        # the heading noise is split around the translation (rot1 / rot2 of PR 5.6)
        th = self.particles[:, 2] + 0.5 * n_rot
        ct, st = np.cos(th), np.sin(th)
        self.particles[:, 0] += ct * bx - st * by
        self.particles[:, 1] += st * bx + ct * by
        self.particles[:, 2] = wrap(self.particles[:, 2] + dth + n_rot)

    # ------------------------------------------------------------------ measurement

    def _distances(self, particles: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """(N, B) surface distances of the scan points seen from each particle, bilinear
        on the padded field (off the map reads the cap)."""
        g = self.geometry
        c = np.cos(particles[:, 2])[:, None]
        s = np.sin(particles[:, 2])[:, None]
        px, py = pts[None, :, 0], pts[None, :, 1]
        # continuous (row, col) in the padded grid, cell centres at integers
        fc = (particles[:, 0:1] + c * px - s * py - g.origin_x) / g.resolution + 0.5
        fr = (particles[:, 1:2] + s * px + c * py - g.origin_y) / g.resolution + 0.5
        np.clip(fc, 0.0, g.width + 1.0, out=fc)
        np.clip(fr, 0.0, g.height + 1.0, out=fr)
        c0 = np.minimum(fc.astype(np.intp), g.width)
        r0 = np.minimum(fr.astype(np.intp), g.height)
        tc = fc - c0
        tr = fr - r0
        flat = self._dgrid.ravel()
        i00 = r0 * (g.width + 2) + c0
        d00 = flat[i00]
        d01 = flat[i00 + 1]
        d10 = flat[i00 + g.width + 2]
        d11 = flat[i00 + g.width + 3]
        return (d00 + (d01 - d00) * tc) * (1.0 - tr) + (d10 + (d11 - d10) * tc) * tr

    def _log_pz(self, d: np.ndarray, sigma: float, range_max: float) -> np.ndarray:
        c = self.config
        return np.log(c.z_hit * np.exp(-0.5 * (d / sigma) ** 2) + c.z_rand / max(range_max, 1e-3))

    def _stand_mask(self, particles: np.ndarray) -> np.ndarray:
        g = self.geometry
        cols = np.floor((particles[:, 0] - g.origin_x) / g.resolution).astype(np.intp) + 1
        rows = np.floor((particles[:, 1] - g.origin_y) / g.resolution).astype(np.intp) + 1
        np.clip(cols, 0, g.width + 1, out=cols)
        np.clip(rows, 0, g.height + 1, out=rows)
        return self._stand[rows, cols]

    def update(self, scan: ScanPoints) -> bool:
        """Weigh the particles by a scan (only after the filter has moved enough, or once
        after initialisation), resample when the weights have degenerated, and refine the
        estimate against the map. Returns whether the particle set was weighed."""
        pts = np.asarray(scan.points, dtype=float).reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) == 0 or len(self.particles) == 0:
            return False
        moving = self._in_ignored(pts)
        if np.count_nonzero(~moving) >= 10:  # (nearly all of it: keep what there is)
            pts = pts[~moving]
        weighed = False
        if self._pending or self._force_update:
            self._weigh(pts, scan.range_max)
            self._pending = self._force_update = False
            weighed = True
        est = self._estimate
        if self.config.refine and est is not None and est.converged:
            self._refine(pts)
        else:
            self._refined = None
        return weighed

    def _weigh(self, pts: np.ndarray, range_max: float) -> None:
        c = self.config
        nb = min(len(pts), c.max_beams)
        beams = pts[np.linspace(0, len(pts) - 1, nb).round().astype(np.intp)]
        d = self._distances(self.particles, beams)
        was_converged = self._estimate is not None and self._estimate.converged
        sigma = c.sigma_hit if was_converged else c.sigma_hit_wide
        raw = self._log_pz(d, sigma, range_max).sum(axis=1)
        off = ~self._stand_mask(self.particles)
        raw[off] -= c.pose_penalty
        settling = self._global_left > 0
        loglik = (c.global_exponent if settling else c.likelihood_exponent) * raw
        self._global_left = max(0, self._global_left - 1)
        # Augmented MCL's average likelihood, on a fixed model and per beam, so that it is
        # comparable across scans with different numbers of returns and across sigmas
        if sigma == c.recovery_sigma:
            stat, ns = raw, nb
        else:  # every third beam is plenty for a scalar average
            stat = self._log_pz(d[:, ::3], c.recovery_sigma, range_max).sum(axis=1)
            ns = d[:, ::3].shape[1]
            stat[off] -= c.pose_penalty
        w_avg = math.exp(_logsumexp(self.log_weights + stat) / ns)
        if self._w_slow <= 0.0:
            self._w_slow = self._w_fast = w_avg
        else:
            self._w_slow += c.recovery_alpha_slow * (w_avg - self._w_slow)
            self._w_fast += c.recovery_alpha_fast * (w_avg - self._w_fast)
        lw = self.log_weights + loglik
        self.log_weights = lw - _logsumexp(lw)
        self.stats.weighed += 1
        self._estimate = self._cluster_estimate(self._odom_applied)
        w = np.exp(self.log_weights)
        ess = 1.0 / float(np.sum(w * w))
        if ess < c.resample_ess_ratio * len(w):
            self._resample(w)

    # ------------------------------------------------------------------ resampling

    def _resample(self, w: np.ndarray) -> None:
        """Low-variance resampling (PR Table 4.4) of a candidate set of max_particles,
        with random particles mixed in (Augmented MCL, PR Table 8.3), cut to the KLD
        count (PR Table 8.4) of the candidates in random order. The likelihood averages
        are not reset after an injection (PR's form; ROS amcl resets them), so a lost
        filter keeps injecting until its fit recovers."""
        c = self.config
        n_max = c.max_particles
        p_inject = 0.0
        if self._w_slow > 0.0:
            p_inject = max(0.0, 1.0 - self._w_fast / self._w_slow)
        self.stats.last_injection_probability = p_inject
        n_rand = int(self.rng.binomial(n_max, p_inject)) if p_inject > 0 else 0
        n_res = n_max - n_rand
        cdf = np.cumsum(w)
        cdf[-1] = 1.0
        u = (self.rng.random() + np.arange(n_res)) / n_res
        idx = np.searchsorted(cdf, u, side="right")
        cand = self.particles[np.minimum(idx, len(w) - 1)]
        resampled = np.ones(n_max, dtype=bool)
        if n_rand:
            cand = np.concatenate([cand, self._random_particles(n_rand)])
            resampled[n_res:] = False
        order = self.rng.permutation(n_max)
        cand, resampled = cand[order], resampled[order]
        m = self._kld_count(cand, resampled)
        self.particles = cand[:m].copy()
        self.log_weights = np.full(m, -math.log(m))
        self.stats.resampled += 1
        self.stats.injected += int(np.count_nonzero(~resampled[:m]))

    def _kld_count(self, cand: np.ndarray, counted: np.ndarray) -> int:
        """Length of the shortest prefix whose ``counted`` (resampled) particles reach the
        KLD bound of the bins they occupy. Injected random particles ride along in
        proportion but open no bins: a few of them must not inflate the set to the
        maximum while tracking, and when most are random (lost) the set grows anyway."""
        c = self.config
        bx, by, byaw = c.kld_bin
        ix = np.floor(cand[:, 0] / bx).astype(np.int64)
        iy = np.floor(cand[:, 1] / by).astype(np.int64)
        ia = np.floor((wrap(cand[:, 2]) + math.pi) / byaw).astype(np.int64)
        keys = (ix + (1 << 20)) * (1 << 40) + (iy + (1 << 20)) * (1 << 20) + ia
        keys = np.where(counted, keys, -1)
        _, first = np.unique(keys, return_index=True)
        new = np.zeros(len(cand), dtype=np.int64)
        new[first] = 1
        new[~counted] = 0
        k = np.cumsum(new)
        n = np.cumsum(counted)
        need = kld_sample_count(k, c.kld_epsilon, c.kld_z)
        total = np.arange(1, len(cand) + 1)
        ok = np.flatnonzero((n >= need) & (total >= c.min_particles))
        return int(ok[0] + 1) if len(ok) else len(cand)

    # ------------------------------------------------------------------ estimate

    def _cluster_estimate(self, odom: Pose2 | None) -> _Estimate:
        """The weighted mean and covariance of the heaviest cluster: particles binned in
        (x, y, yaw), connected occupied bins form a cluster (yaw wraps around)."""
        c = self.config
        p = self.particles
        w = np.exp(self.log_weights)
        w = w / w.sum()
        g = self.geometry
        bx, by, byaw = c.cluster_bin
        x0, y0, x1, y1 = g.extent
        nx = int(math.ceil((x1 - x0) / bx)) + 2
        ny = int(math.ceil((y1 - y0) / by)) + 2
        na = int(math.ceil(2 * math.pi / byaw))
        ix = np.clip(np.floor((p[:, 0] - x0) / bx).astype(np.intp) + 1, 0, nx - 1)
        iy = np.clip(np.floor((p[:, 1] - y0) / by).astype(np.intp) + 1, 0, ny - 1)
        ia = np.floor((wrap(p[:, 2]) + math.pi) / byaw).astype(np.intp) % na
        occ = np.zeros((nx, ny, na + 1), dtype=bool)
        occ[ix, iy, ia] = True
        occ[:, :, na] = occ[:, :, 0]  # the wrap: yaw bin 0 again after the last
        labels, n_lab = ndimage.label(occ, structure=np.ones((3, 3, 3), dtype=bool))
        if n_lab > 1:
            a = labels[:, :, 0].ravel()
            b = labels[:, :, na].ravel()
            sel = (a > 0) & (b > 0) & (a != b)
            graph = coo_matrix(
                (np.ones(int(sel.sum())), (a[sel], b[sel])), shape=(n_lab + 1, n_lab + 1)
            )
            _, merged = connected_components(graph, directed=False)
        else:
            merged = np.arange(n_lab + 1)
        cid = merged[labels[ix, iy, ia]]
        mass = np.bincount(cid, weights=w)
        best = int(np.argmax(mass))
        sel = cid == best
        ws = w[sel] / mass[best]
        ps = p[sel]
        yaw = math.atan2(float(ws @ np.sin(ps[:, 2])), float(ws @ np.cos(ps[:, 2])))
        mean = np.array([float(ws @ ps[:, 0]), float(ws @ ps[:, 1]), yaw])
        r = ps - mean
        r[:, 2] = wrap(r[:, 2])
        cov = (r * ws[:, None]).T @ r
        sx, sy, sa = np.sqrt(np.maximum(np.diag(cov), 0.0))
        converged = (
            self._global_left == 0
            and mass[best] >= c.converged_mass
            and max(sx, sy) <= c.converged_std_xy
            and sa <= c.converged_std_yaw
        )
        pose = (float(mean[0]), float(mean[1]), float(mean[2]))
        return _Estimate(
            pose, cov, odom, float(mass[best]), bool(converged), int(np.count_nonzero(mass))
        )

    def _refine(self, pts: np.ndarray) -> None:
        """Gauss-Newton of the scan against the distance field, from the particle estimate:
        minimise sum rho(d(T p_i) - surface) over T (Huber rho, far points ignored)."""
        c = self.config
        nb = min(len(pts), c.refine_max_beams)
        pts = pts[np.linspace(0, len(pts) - 1, nb).round().astype(np.intp)]
        start = self._particle_pose()
        x = np.array(start, dtype=float)
        inl = np.zeros(len(pts), dtype=bool)
        it = 0
        for it in range(1, c.refine_iterations + 1):  # noqa: B007 - reported in stats
            cs, sn = math.cos(x[2]), math.sin(x[2])
            wx = x[0] + cs * pts[:, 0] - sn * pts[:, 1]
            wy = x[1] + sn * pts[:, 0] + cs * pts[:, 1]
            d, grad = self._refine_field.distance_and_gradient(np.stack([wx, wy], axis=1))
            r = d - self._refine_surface
            inl = d < c.refine_inlier_distance
            if np.count_nonzero(inl) < 6:
                break
            a = np.abs(r)
            hw = np.where(a <= c.refine_huber, 1.0, c.refine_huber / np.maximum(a, 1e-9))
            hw = hw * inl
            dth = grad[:, 0] * (-sn * pts[:, 0] - cs * pts[:, 1]) + grad[:, 1] * (
                cs * pts[:, 0] - sn * pts[:, 1]
            )
            jac = np.stack([grad[:, 0], grad[:, 1], dth], axis=1)
            h = (jac * hw[:, None]).T @ jac
            b = (jac * hw[:, None]).T @ r
            h += 1e-6 * np.trace(h) * np.eye(3) + 1e-9 * np.eye(3)
            step = -np.linalg.solve(h, b)
            x += step
            x[2] = wrap(x[2])
            if abs(step[0]) + abs(step[1]) < 1e-4 and abs(step[2]) < 1e-4:
                break
        shift = math.hypot(x[0] - start[0], x[1] - start[1])
        turn = abs(wrap(x[2] - start[2]))
        frac = float(np.count_nonzero(inl)) / max(len(pts), 1)
        if (
            shift <= c.refine_max_shift[0]
            and turn <= c.refine_max_shift[1]
            and frac >= c.refine_min_inliers
        ):
            pose = (float(x[0]), float(x[1]), float(wrap(x[2])))
            self._refined = _Refined(pose, self._odom_latest, frac, it)
            self.stats.refined += 1
        else:
            self._refined = None

    def _particle_pose(self) -> Pose2:
        est = self._estimate
        assert est is not None
        return _follow(est.pose, est.odom, self._odom_latest)

    def estimate(self) -> tuple[Pose2, np.ndarray]:
        """(pose, 3x3 covariance) of the robot in the map at the latest odometry: the
        scan-refined pose once converged, else the best cluster's mean."""
        if self._estimate is None:
            raise RuntimeError("the filter has not been initialised")
        cov = self._estimate.cov.copy()
        if self._refined is not None:
            return _follow(self._refined.pose, self._refined.odom, self._odom_latest), cov
        return self._particle_pose(), cov

    @property
    def converged(self) -> bool:
        """Whether one cluster holds most of the weight and is tight (the config's bounds)."""
        return self._estimate is not None and self._estimate.converged

    @property
    def particle_count(self) -> int:
        """How many particles the filter holds now."""
        return len(self.particles)

    @property
    def weights(self) -> np.ndarray:
        """Normalised particle weights."""
        return np.exp(self.log_weights)

    def map_to_odom(self, odom_pose: Pose2) -> Pose2:
        """The map -> odom transform, estimate ⊕ odom⁻¹ (what a localiser publishes so
        that map -> odom -> base gives the robot's map pose); ``odom_pose`` should be the
        one last given to ``predict``."""
        pose, _ = self.estimate()
        return compose(pose, invert(odom_pose))


def _follow(pose: Pose2, odom_then: Pose2 | None, odom_now: Pose2 | None) -> Pose2:
    """A pose carried along by the odometry from ``odom_then`` to ``odom_now``."""
    if odom_then is None or odom_now is None:
        return pose
    return compose(pose, compose(invert(odom_then), odom_now))


def _logsumexp(a: np.ndarray) -> float:
    m = float(np.max(a))
    if not math.isfinite(m):
        return m
    return m + math.log(float(np.sum(np.exp(a - m))))
