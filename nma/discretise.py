"""A scene's model, built once, as its parts: the mesh and its quadrature (Mesh), the boundary
(Boundary: prescribed dofs, actuation, loads), the solid whose energy is integrated (Solid: the
mesh, the material and the pores' contact), the design that places the control points, and the
tracked points.  It joins the geometry and the mechanics, so it sits above both.

The parts are static numpy data; one differentiable function, `reference_points(params)`, maps the
design parameters to the merged reference control points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from .errors import ConfigError
from .geometry.boundary import Boundary
from .geometry.bspline import DESIGN_CTRL, basis_matrix, greville, refinement_operator
from .geometry.design import make_design
from .geometry.mesh import Mesh
from .geometry.options import Resolution
from .geometry.scene import PatchSceneSpec, SceneSpec
from .mechanics.material import Material
from .mechanics.solid import Solid


@dataclass(frozen=True, eq=False)
class Discretisation:
    spec: SceneSpec | PatchSceneSpec
    design: object  # nma.geometry.design: the parameters that place the control points
    solid: Solid  # the mesh, the material and the pores' contact
    boundary: Boundary
    # name -> (point indices (m*m,), basis weights (m*m,))
    tracked: dict = field(default_factory=dict)
    # a dead load per unit reference area (2,), density x gravity; None: none
    body_force: tuple[float, float] | None = None
    # the density that body force was made with, where known: a run in time's mass must be the same
    body_density: float | None = None

    @property
    def mesh(self) -> Mesh:
        return self.solid.mesh

    @property
    def material(self) -> Material:
        return self.solid.material

    @property
    def contact(self):
        """The pores' contact model (nma.mechanics.contact.ContactModel), None without contact."""
        return self.solid.contact

    def analysis_nets(self, params) -> jnp.ndarray:
        """(P, m, m, 2) analysis control nets: the design nets refined by knot insertion (exact)."""
        fidelity = self.mesh.fidelity
        R = jnp.asarray(refinement_operator(fidelity.ctrl_per_patch, fidelity.grading))
        return jnp.einsum("ia,pabd,jb->pijd", R, self.design.nets(params), R)

    def reference_points(self, params) -> jnp.ndarray:
        """(n_points, 2) merged reference control points; differentiable in the design
        parameters."""
        return self.analysis_nets(params).reshape(-1, 2)[self.mesh.representative]

    def init_params(self):
        return self.design.init_params()

    def tracked_points(self, points: jnp.ndarray) -> dict[str, jnp.ndarray]:
        """Positions of the tracked material points for control points `points` (X or X + u)."""
        return {k: jnp.asarray(w) @ points[idx] for k, (idx, w) in self.tracked.items()}

    def pore_boundary(self) -> tuple[np.ndarray, np.ndarray]:
        """Material points on the central pore's edge, counter-clockwise from its first ring node:
        per side, the design net's Greville abscissae 0, 1/6, 1/2, 5/6 on the inner edge (where the
        5 x 5 design's control points project onto the curve), 4 M points in all; see
        material_points."""
        design = self.design
        if not len(getattr(design, "central", ())):
            raise ConfigError(f"scene {self.spec.name} has no central pore")
        first = 4 * len(design.porous)
        along = greville(DESIGN_CTRL)[:-1]
        patches = np.repeat(first + np.arange(len(design.central)), len(along))
        xi = np.stack([np.tile(along, len(design.central)), np.ones(len(patches))], axis=1)
        return self.mesh.material_points(patches, xi)


def _locate(
    nets: np.ndarray, target: np.ndarray, tol: float, grading: float
) -> tuple[int, np.ndarray]:
    """Patch and parametric coordinates of a reference point (Newton inversion of each patch
    map)."""
    m = nets.shape[1]
    basis = lambda x, d=0: basis_matrix(x, m, d, grading)[0]
    lo, hi = nets.min(axis=(1, 2)) - tol, nets.max(axis=(1, 2)) + tol
    # the convex hull property: only a patch whose box holds the point can hold it
    candidates = np.flatnonzero(np.all((lo <= target) & (target <= hi), axis=1))
    for p in candidates:
        net = nets[p]
        xi = np.array([0.5, 0.5])
        for _ in range(30):
            B = [basis(xi[k : k + 1]) for k in range(2)]
            dB = [basis(xi[k : k + 1], 1) for k in range(2)]
            x = np.einsum("i,j,ijd->d", B[0], B[1], net)
            J = np.stack(
                [
                    np.einsum("i,j,ijd->d", dB[0], B[1], net),
                    np.einsum("i,j,ijd->d", B[0], dB[1], net),
                ],
                axis=1,
            )
            step = np.linalg.lstsq(J, target - x, rcond=None)[0]
            xi = np.clip(xi + step, 0.0, 1.0)
            if np.linalg.norm(step) < 1e-14:
                break
        B = [basis(xi[k : k + 1]) for k in range(2)]
        if np.linalg.norm(np.einsum("i,j,ijd->d", B[0], B[1], net) - target) < tol:
            return int(p), xi
    return -1, np.zeros(2)


def discretise(
    spec: SceneSpec | PatchSceneSpec,
    fidelity=None,
    contact=None,
    material: Material | str = "displacement",
    body_force: tuple[float, float] | None = None,
    body_density: float | None = None,
) -> Discretisation:
    """The analysis model of a scene at a concrete `fidelity` (a Resolution or a setting with its
    fields: the control points and Gauss points per patch, the inversion barrier; an `auto` is
    decided by the command, nma.resolve, before it gets here; None: the paper's 5 x 5), with the
    pores' self-contact where `contact` (nma.mechanics.contact.ContactSettings) is given, and the
    `material` (its law and formulation; a formulation's name, one of
    nma.mechanics.options.FORMULATIONS: the Neo-Hookean law's), and a dead load per unit reference
    area `body_force` (density x gravity: SceneConfig.body_force), None: none, made with the
    density `body_density` where given (Dynamics refuses a mass of another)."""
    material = material if isinstance(material, Material) else Material(material)
    fidelity = Resolution.of(fidelity)
    design = make_design(spec)
    m, g = fidelity.ctrl_per_patch, fidelity.grading
    R = refinement_operator(m, g)
    # topology from a canonical design (mid radii, corners at rest): which points coincide must not
    # depend on the initial radii, or a radius at a bound would merge a pore's sides into one point
    canonical = np.asarray(design.nets(design.topology_params()))
    nets = np.einsum("ia,pabd,jb->pijd", R, canonical, R)  # (P, m, m, 2)
    tol = 1e-7 * np.ptp(nets.reshape(-1, 2), axis=0).max()
    mesh = Mesh.of(nets, fidelity, tol)
    points = nets.reshape(-1, 2)[mesh.representative]
    boundary = Boundary.of(spec, mesh, nets, points, tol)

    tracked = {}
    for name, xy in spec.tracked.items():
        patch, xi = _locate(nets, np.asarray(xy, float), tol, g)
        if patch < 0:
            raise ConfigError(f"scene {spec.name}: tracked point {name} at {xy} lies in no patch")
        w = np.einsum(
            "i,j->ij", basis_matrix(xi[:1], m, grading=g)[0], basis_matrix(xi[1:], m, grading=g)[0]
        ).ravel()
        keep = w > 1e-15
        tracked[name] = (mesh.patch_points[patch][keep], w[keep])

    model = None
    if contact is not None:
        from .geometry.outline import oriented_loops
        from .mechanics.contact import build

        model = build(oriented_loops(mesh, points)[1:], points, contact, g)
    return Discretisation(
        spec=spec,
        design=design,
        solid=Solid(mesh, material, model),
        boundary=boundary,
        tracked=tracked,
        body_force=None if body_force is None else tuple(float(b) for b in body_force),
        body_density=None if body_force is None or body_density is None else float(body_density),
    )


__all__ = ["Resolution", "Discretisation", "discretise", "DESIGN_CTRL"]
