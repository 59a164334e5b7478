"""Deformation fields to HDF5, with an XDMF companion that ParaView opens directly."""

from __future__ import annotations

from pathlib import Path

import h5py
import jax
import jax.numpy as jnp
import numpy as np

from ..discretise import Discretisation
from ..geometry.sampling import quad_cells, sample_jacobian, sample_positions

# one HDF5 dataset as an XDMF data item: its dimensions, number type and path in the .h5 file
_ITEM = (
    '<DataItem Dimensions="{dims}" NumberType="{kind}" Precision="8" Format="HDF">'
    "{{h5}}:{path}</DataItem>"
)
_XDMF = f"""<?xml version="1.0" ?>
<Xdmf Version="3.0">
  <Domain>
    <Grid Name="{{name}}" GridType="Uniform">
      <Topology TopologyType="Quadrilateral" NumberOfElements="{{n_cells}}">
        {_ITEM.format(dims="{n_cells} 4", kind="Int", path="/mesh/cells")}
      </Topology>
      <Geometry GeometryType="XY">
        {_ITEM.format(dims="{n_nodes} 2", kind="Float", path="/mesh/reference")}
      </Geometry>
      <Attribute Name="displacement" AttributeType="Vector" Center="Node">
        {_ITEM.format(dims="{n_nodes} 3", kind="Float", path="/fields/displacement")}
      </Attribute>
      <Attribute Name="J" AttributeType="Scalar" Center="Node">
        {_ITEM.format(dims="{n_nodes}", kind="Float", path="/fields/J")}
      </Attribute>
{{extra}}    </Grid>
  </Domain>
</Xdmf>
"""
_SCALAR = f"""      <Attribute Name="{{name}}" AttributeType="Scalar" Center="Node">
        {_ITEM.format(dims="{n_nodes}", kind="Float", path="/fields/{name}")}
      </Attribute>
"""


def sampler(disc: Discretisation, X, samples: int = 9, compiled: bool = True):
    """u -> (reference, deformed, det F) at the s x s material points of every patch, for the design
    X. Compiled, one call per state, for writing many states' fields (eager, each call's dispatch
    costs more than compiling once)."""
    X = jnp.asarray(X)
    ref = np.asarray(sample_positions(disc.mesh, X, samples))
    deformed = lambda u: (
        sample_positions(disc.mesh, X + u, samples),
        sample_jacobian(disc.mesh, X, u, samples),
    )
    if compiled:
        deformed = jax.jit(deformed)
    return lambda u: (ref, *(np.asarray(a) for a in deformed(jnp.asarray(u))))


def write_fields(
    path: Path,
    disc: Discretisation,
    X,
    u,
    samples: int = 9,
    scalars: dict | None = None,
    attrs: dict | None = None,
    sample=None,
) -> tuple[Path, Path]:
    """Write control points and sampled fields to `path` (.h5) and `path.with_suffix('.xdmf')`.

    The sampled mesh joins s x s material points per patch into quads; displacement is written with
    a zero third component so ParaView's Warp By Vector applies it directly.  `sample`: this
    design's `sampler(disc, X, samples)`, where many states are written."""
    path = Path(path).with_suffix(".h5")
    path.parent.mkdir(parents=True, exist_ok=True)
    X, u = np.asarray(X), np.asarray(u)
    ref, cur, J = (sample or sampler(disc, X, samples, compiled=False))(u)
    ref, cur, J = ref.reshape(-1, 2), cur.reshape(-1, 2), J.reshape(-1)
    cells = quad_cells(disc.mesh.n_patches, samples)
    disp = np.concatenate([cur - ref, np.zeros((len(ref), 1))], axis=1)
    tmp = path.with_suffix(".h5.tmp")
    with h5py.File(tmp, "w") as f:
        f.create_dataset("control/reference", data=X)
        f.create_dataset("control/displacement", data=u)
        f.create_dataset("control/patch_points", data=disc.mesh.patch_points)
        f.create_dataset("mesh/reference", data=ref)
        f.create_dataset("mesh/deformed", data=cur)
        f.create_dataset("mesh/cells", data=cells)
        f.create_dataset("fields/displacement", data=disp)
        f.create_dataset("fields/J", data=J)
        for name, v in (scalars or {}).items():
            f.create_dataset(f"fields/{name}", data=np.asarray(v).reshape(-1))
        f.attrs["scene"] = disc.spec.name
        f.attrs["samples_per_side"] = samples
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
    tmp.replace(path)
    extra = "".join(_SCALAR.format(name=n, n_nodes=len(ref), h5=path.name) for n in (scalars or {}))
    xdmf = path.with_suffix(".xdmf")
    xdmf.write_text(
        _XDMF.format(
            name=disc.spec.name, n_cells=len(cells), n_nodes=len(ref), h5=path.name, extra=extra
        )
    )
    return path, xdmf


def write_trajectory(
    path: Path, times, u, v, datasets: dict | None = None, attrs: dict | None = None
) -> Path:
    """Write trajectories to `path` (.h5), atomically: `times` (k,), the control points'
    displacements `u` and velocities `v` at those times ((k, n_points, 2), or (samples, k,
    n_points, 2) for several), and further `datasets` by name ("tracked/pointer": a group's member)
    and `attrs`.  The one writer of trajectories (nma.simulate's trajectory.h5, a run's
    fields/trajectories.h5)."""
    path = Path(path).with_suffix(".h5")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".h5.tmp")
    with h5py.File(tmp, "w") as f:
        f["times"], f["u"], f["v"] = np.asarray(times), np.asarray(u), np.asarray(v)
        for name, data in (datasets or {}).items():
            f[name] = np.asarray(data)
        for k, value in (attrs or {}).items():
            f.attrs[k] = value
    tmp.replace(path)
    return path
