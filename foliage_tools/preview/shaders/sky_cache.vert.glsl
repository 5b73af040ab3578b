// Transform feedback: the open fraction of the sky at every vertex of every instance, for
// the front (x) and back (y) face. The sky does not move, so this runs once per scene and
// the main pass reads the result (scene.vert.glsl, SKY_CACHED). Preceded by sky.glsl.

uniform vec3 u_up;

in vec3 in_position;
in vec3 in_normal;
in mat4 in_model;
in mat3 in_normal_matrix;

out vec2 o_sky;

void main() {
    vec3 world = (in_model * vec4(in_position, 1.0)).xyz;
    vec3 n = in_normal_matrix * in_normal;
    n = length(n) > 0.0 ? normalize(n) : u_up;  // degenerate triangles draw nothing
    o_sky = vec2(sky_visibility(world, n), sky_visibility(world, -n));
}
