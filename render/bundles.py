"""The render kernels' arguments as bundles: Taichi argpacks of the device arrays that travel
together (the pattern of taichi_hair/solver/step/bundles.py), built once per frame, shadow map
or bin pass by their owners, and handed to `ti.func`s as `ti.template()`.

Argpacks hold arrays only; numbers, vectors and matrices stay plain kernel arguments: Taichi
1.7 compiles a value read from an argpack (or a struct argument) into other float code than
the same value as an argument (fast math reorders the arithmetic around it), and frames then
differ in the last bit. Member names differ across bundles: Taichi 1.7 confuses argpack
members of the same name.
"""

import taichi as ti

from .camera import f32, vec3f, vec4f
from .raster import vec2f, vec3i

vec2i = ti.types.vector(2, ti.i32)

# the hair's per-vertex arrays, (V,) unless noted (uploaded by `render.frame`): world positions [m]
# and widths [m], each segment's first vertex (S,), each vertex's strand neighbours (tangent
# from nbr[1] - nbr[0]), Kajiya-Kay colour, fibre absorption [1/radius] and roughness beta_m,
# projected widths [px] and screen points (sx, sy, depth, inv_w), the key light's
# transmittance, the shaded colour (linear rgb, opacity) and the binned-segment marks
HairArgs = ti.types.argpack(
    hair_x=ti.types.ndarray(dtype=vec3f, ndim=1),
    hair_width=ti.types.ndarray(dtype=f32, ndim=1),
    hair_seg=ti.types.ndarray(dtype=ti.i32, ndim=1),
    hair_nbr=ti.types.ndarray(dtype=vec2i, ndim=1),
    hair_colour=ti.types.ndarray(dtype=vec3f, ndim=1),
    hair_sigma=ti.types.ndarray(dtype=vec3f, ndim=1),
    hair_beta_m=ti.types.ndarray(dtype=f32, ndim=1),
    hair_width_px=ti.types.ndarray(dtype=f32, ndim=1),
    hair_screen=ti.types.ndarray(dtype=vec4f, ndim=1),
    hair_shadow=ti.types.ndarray(dtype=f32, ndim=1),
    hair_rgba=ti.types.ndarray(dtype=vec4f, ndim=1),
    hair_mark=ti.types.ndarray(dtype=ti.i32, ndim=1))

# the merged meshes' arrays (uploaded by `render.frame`): per vertex (V,) the screen points, world
# positions [m], normals and linear albedo; per face (F,) the vertex indices and (specular,
# shininess)
MeshArgs = ti.types.argpack(
    mesh_screen=ti.types.ndarray(dtype=vec4f, ndim=1),
    mesh_faces=ti.types.ndarray(dtype=vec3i, ndim=1),
    mesh_x=ti.types.ndarray(dtype=vec3f, ndim=1),
    mesh_normal=ti.types.ndarray(dtype=vec3f, ndim=1),
    mesh_albedo=ti.types.ndarray(dtype=vec3f, ndim=1),
    mesh_material=ti.types.ndarray(dtype=vec2f, ndim=1))

# one directional light's shadow maps (`shadows.ShadowMap.args`): the hair's nearest depth z0
# (R, R) [m], cumulative opacity (R, R, L), slab bounds (L + 1,) [m] and the meshes' depth keys
# (R, R); the map's view, proj and params travel beside it as values
ShadowMapArgs = ti.types.argpack(
    shadow_z0=ti.types.ndarray(dtype=f32, ndim=2),
    shadow_opacity=ti.types.ndarray(dtype=f32, ndim=3),
    shadow_bounds=ti.types.ndarray(dtype=f32, ndim=1),
    shadow_mesh_key=ti.types.ndarray(dtype=ti.i64, ndim=2))

# the directional lights shading the hair in one pass, (K,) each: the unit direction towards
# light k, its irradiance [W/m^2] (linear rgb), and its shadow terms at every vertex (K, V)
# (`shadows.points_shadow_terms`)
LightSetArgs = ti.types.argpack(
    light_to=ti.types.ndarray(dtype=vec3f, ndim=1),
    light_irradiance=ti.types.ndarray(dtype=vec3f, ndim=1),
    light_terms=ti.types.ndarray(dtype=vec3f, ndim=2))

# a fibre material's device tables (`fibre_lobes.table_args`, flat): log N, log A and the dual
# scattering table; its lobes' tilts (`HairMaterial.shifts`) travel beside them as values
FibreTableArgs = ti.types.argpack(
    fibre_ntab=ti.types.ndarray(dtype=f32, ndim=1),
    fibre_atab=ti.types.ndarray(dtype=f32, ndim=1),
    fibre_dtab=ti.types.ndarray(dtype=f32, ndim=1))

# the tile grid's depth bins (`tiles.bin_hair`), per (tile, bin) cell (tiles x N_BINS,): the
# ranked entries' count, the further entries' count (then the scatter's cursor), the cells'
# offsets (one more), each segment's rank in its first RANKED cells (S, RANKED), and the
# entries' sort keys
TileBinArgs = ti.types.argpack(
    bin_count=ti.types.ndarray(dtype=ti.i32, ndim=1),
    bin_extra=ti.types.ndarray(dtype=ti.i32, ndim=1),
    bin_offsets=ti.types.ndarray(dtype=ti.i32, ndim=1),
    bin_rank=ti.types.ndarray(dtype=ti.i32, ndim=2),
    bin_items=ti.types.ndarray(dtype=ti.i64, ndim=1))

# the meshes' pixels (`render.frame`, `raster.mark_mesh_edges`): the nearest face's depth key
# per pixel (H, W), the slot of each pixel near a mesh edge (-1 elsewhere) (H, W), the depth
# keys at those pixels' EDGE_SAMPLES^2 sub-pixel centres (slots, EDGE_SAMPLES^2), the linear
# radiance `shading.shade_mesh` writes (H, W), and which mesh each face belongs to (F,) (where
# two meshes meet is an edge too: `raster.sub_pixel_edge`)
MeshPixelArgs = ti.types.argpack(
    pixel_part=ti.types.ndarray(dtype=ti.i32, ndim=1),
    pixel_key=ti.types.ndarray(dtype=ti.i64, ndim=2),
    pixel_edge_index=ti.types.ndarray(dtype=ti.i32, ndim=2),
    pixel_sub_key=ti.types.ndarray(dtype=ti.i64, ndim=2),
    pixel_base=ti.types.ndarray(dtype=vec3f, ndim=2))
