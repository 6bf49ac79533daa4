"""Part meshes (alpha shapes of Gaussian centres) and antipodal parallel-jaw grasps.

Owns: turning a part's point set into a closed mesh (`build_part_mesh`) and sampling,
scoring and augmenting antipodal grasps on it (`sample_antipodal_grasps`), and level pinches
across a part's footprint seen from above (`sample_topdown_grasps`, for parts lying flat), all
in the part frame. Does not own: which part to grasp (`rsrd_jax.hands`), robot reachability or
collision (`rsrd_jax.plan`).
"""

from ._antipodal import GraspConfig as GraspConfig
from ._antipodal import GraspResult as GraspResult
from ._antipodal import PartGrasps as PartGrasps
from ._antipodal import merge_grasps as merge_grasps
from ._antipodal import sample_antipodal_grasps as sample_antipodal_grasps
from ._antipodal import sample_part_grasps as sample_part_grasps
from ._mesh import MeshConfig as MeshConfig
from ._mesh import PartMesh as PartMesh
from ._mesh import build_part_mesh as build_part_mesh
from ._topdown import TopDownConfig as TopDownConfig
from ._topdown import sample_topdown_grasps as sample_topdown_grasps

__all__ = [
    "GraspConfig",
    "GraspResult",
    "MeshConfig",
    "PartGrasps",
    "PartMesh",
    "TopDownConfig",
    "build_part_mesh",
    "merge_grasps",
    "sample_antipodal_grasps",
    "sample_part_grasps",
    "sample_topdown_grasps",
]
