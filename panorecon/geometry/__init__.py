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
from .depth import DEPTH_KINDS, ViewDepth
from .pointcloud import PointCloud, erp_point_cloud
