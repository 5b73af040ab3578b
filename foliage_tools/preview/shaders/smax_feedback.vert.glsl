// Transform feedback: every term of Boulanger's model (boulanger.glsl) at every vertex of
// every instance, as the main pass evaluates it, read back by Renderer.smax_irradiance so
// tests can hold the shader to foliage_tools/lighting/envelope/boulanger.py. Preceded by
// boulanger.glsl.

uniform vec3 u_sun_dir;            // world, toward the sun
uniform vec3 u_smax_sky[8];        // L_sky(w_j) of eq. (5.29)

in vec3 in_normal;                 // front normal, prototype frame
in vec4 in_smax0;                  // s_max(P, w_0..w_3)
in vec4 in_smax1;                  // s_max(P, w_4..w_7)
in mat4 in_model;
in mat3 in_normal_matrix;

out vec2 o_direct;                 // unit-sun direct irradiance, front and back (eq. (5.8))
out vec3 o_scattered_front;        // unit-sun one-bounce irradiance (eqs. (5.11), (5.24))
out vec3 o_scattered_back;
out vec3 o_sky_front;              // sky and ground irradiance (eq. (5.6))
out vec3 o_sky_back;

void main() {
    // the sun in the prototype's frame: inverse of the instance's linear part, the
    // transpose of the normal matrix (geometry/sun.py to_prototype_space)
    vec3 light = transpose(in_normal_matrix) * u_sun_dir;
    light = length(light) > 0.0 ? normalize(light) : u_sun_dir;  // zero-scale instances draw nothing
    vec3 n = in_normal;
    o_direct = smax_sun_direct(n, in_smax0, in_smax1, light);
    smax_sun_indirect(n, in_smax0, in_smax1, light, o_scattered_front, o_scattered_back);
    smax_sky(n, in_smax0, in_smax1, u_smax_sky, o_sky_front, o_sky_back);
}
