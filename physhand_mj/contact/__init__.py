"""SDF contact between the skin and object geoms (paper section 3.3).

``Objects`` holds the geoms (analytic SDFs per MuJoCo geom type, meshes through a BVH);
``Contact`` records broadphase + decision point + Eq. 9 projection into the solver's substeps.
"""

from physhand_mj.contact.contact import Contact
from physhand_mj.contact.objects import Objects, bounding_radius

__all__ = ["Contact", "Objects", "bounding_radius"]
