// Vertex stage shared by every pass: leaves, wood and the ground plane, and (with
// DEPTH_ONLY) the shadow and sky depth passes. Preceded by sky.glsl.
// Geometry is in prototype space; each instance brings its world-from-prototype matrix
// (column-vector convention, foliage_tools/scene/model.py) and the matrix for normals.

uniform vec3 u_up;
uniform vec3 u_sun_dir;

in vec3 in_position;
in vec3 in_normal;        // the triangle's right-handed (front) unit normal, the same at its 3 corners
in mat4 in_model;         // per instance
in mat3 in_normal_matrix; // per instance: inverse transpose of the model's 3x3 part

#ifdef HAS_INDIRECT
#ifdef SMAX_MODEL
// boulanger2008 sec. 5.6: s_max(P, w_j) of the leaf as two vec4 per vertex; the scattered
// sun light is evaluated here (Algorithm 13, boulanger.glsl) for the current sun
in vec4 in_smax0;
in vec4 in_smax1;
#elif defined(LB_RELIGHT)
// steele2010 sec. 3.1: E_scattered of the 18 Kronecker bases per vertex (texel vertex * 18 + k) and,
// per instance, the three bases whose hull face the sun (in the instance's frame) falls in, with
// their barycentric weights (renderer._lb_weights): relit for the current sun
uniform sampler2D u_lb_bases;
uniform int u_lb_width;
in vec3 in_lb_index;
in vec3 in_lb_weight;
vec3 lb_base(float k) {
    int t = gl_VertexID * 18 + int(k + 0.5);
    return texelFetch(u_lb_bases, ivec2(t % u_lb_width, t / u_lb_width), 0).rgb;
}
#else
in vec3 in_indirect;  // E_scattered at this corner: scattered irradiance, both faces summed
#endif
out vec3 v_indirect_front;  // scattered irradiance reaching the front face ...
out vec3 v_indirect_back;   // ... and the back face
uniform vec3 u_sun_irradiance;
#endif

uniform mat4 u_view_projection;

#ifdef SKY_CACHED
uniform sampler2D u_sky_cache;  // RG: sky visibility of the front and back face
uniform int u_sky_cache_width;
uniform int u_vertex_count;     // vertices per instance
#endif

#ifndef DEPTH_ONLY
out vec3 v_world;
flat out vec3 v_normal;   // front normal in world space (not normalised)
out vec2 v_sky;           // open fraction of the sky seen by the front (x) and back (y) face
#endif

void main() {
    vec4 world = in_model * vec4(in_position, 1.0);
#ifndef DEPTH_ONLY
    v_world = world.xyz;
    v_normal = in_normal_matrix * in_normal;
#ifdef SKY_CACHED
    // computed once per scene by sky_cache.vert.glsl: one texel per (instance, vertex)
    int index = gl_InstanceID * u_vertex_count + gl_VertexID;
    v_sky = texelFetch(u_sky_cache, ivec2(index % u_sky_cache_width, index / u_sky_cache_width), 0).xy;
#else
    vec3 n = length(v_normal) > 0.0 ? normalize(v_normal) : u_up;  // degenerate triangles draw nothing
    v_sky = u_sky_count > 0 ? vec2(sky_visibility(world.xyz, n), sky_visibility(world.xyz, -n)) : vec2(1.0);
#endif
#endif
#ifdef HAS_INDIRECT
#ifdef SMAX_MODEL
    // Algorithm 8: the model's terms are per leaf, so per vertex. The sun in the prototype's
    // frame is the inverse of the instance's linear part applied to it, i.e. the transpose
    // of the normal matrix (geometry/sun.py to_prototype_space).
    vec3 light = transpose(in_normal_matrix) * u_sun_dir;
    light = length(light) > 0.0 ? normalize(light) : u_sun_dir;  // zero-scale instances draw nothing
    smax_sun_indirect(in_normal, in_smax0, in_smax1, light, v_indirect_front, v_indirect_back);
    v_indirect_front *= u_sun_irradiance;
    v_indirect_back *= u_sun_irradiance;
#elif defined(LB_RELIGHT)
    vec3 e = in_lb_weight.x * lb_base(in_lb_index.x) + in_lb_weight.y * lb_base(in_lb_index.y)
           + in_lb_weight.z * lb_base(in_lb_index.z);
    v_indirect_front = 0.5 * e;  // both faces summed, half to each (as for a baked E_scattered)
    v_indirect_back = 0.5 * e;
#else
    // a baked E_scattered is both faces summed (DESIGN.md section 3); without its split
    // between the faces each face gets half
    v_indirect_front = 0.5 * in_indirect;
    v_indirect_back = 0.5 * in_indirect;
#endif
#endif
    gl_Position = u_view_projection * world;
}
