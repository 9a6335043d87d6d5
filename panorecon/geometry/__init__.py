"""Pure sphere and camera geometry: ERP <-> directions, pinhole cameras, view layouts, remapping."""

from .camera import (
    PinholeCamera,
    centred_camera,
    intrinsics_from_fov,
    look_at_rotation,
    look_at_viewmat,
    pixel_rays,
    viewmat_from_pose,
)
from .depth import DEPTH_KINDS, ViewDepth
from .layouts import (
    LAYOUT_NAMES,
    Layout,
    coverage_fraction,
    cube_directions,
    fibonacci_directions,
    icosahedron_face_centres,
    icosahedron_faces,
    icosahedron_vertices,
    latlong_directions,
    make_layout,
)
from .pointcloud import PointCloud, back_project_erp, erp_point_cloud, thin_on_sphere
from .remap import erp_to_perspective, pad_erp, perspective_to_erp, sample_erp
from .sphere import (
    direction_to_erp_pixel,
    direction_to_lonlat,
    distance_to_points,
    erp_directions,
    erp_pixel_solid_angle,
    erp_pixel_to_lonlat,
    lonlat_to_direction,
    lonlat_to_erp_pixel,
)

__all__ = [
    "DEPTH_KINDS",
    "LAYOUT_NAMES",
    "centred_camera",
    "coverage_fraction",
    "cube_directions",
    "direction_to_erp_pixel",
    "direction_to_lonlat",
    "distance_to_points",
    "erp_directions",
    "erp_pixel_solid_angle",
    "erp_pixel_to_lonlat",
    "erp_point_cloud",
    "back_project_erp",
    "thin_on_sphere",
    "erp_to_perspective",
    "fibonacci_directions",
    "icosahedron_face_centres",
    "icosahedron_faces",
    "icosahedron_vertices",
    "intrinsics_from_fov",
    "latlong_directions",
    "Layout",
    "lonlat_to_direction",
    "lonlat_to_erp_pixel",
    "look_at_rotation",
    "look_at_viewmat",
    "make_layout",
    "pad_erp",
    "perspective_to_erp",
    "PinholeCamera",
    "pixel_rays",
    "PointCloud",
    "sample_erp",
    "ViewDepth",
    "viewmat_from_pose",
]
