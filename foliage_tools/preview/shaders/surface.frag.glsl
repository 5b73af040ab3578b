// Radiance toward the camera of leaves (LEAF), bark (WOOD) or the ground plane (GROUND).
// Output 0: linear RGB radiance, alpha 1 where geometry is. Output 1: 1 on the tree.

#if defined(LEAF)
uniform vec3 u_rho_rf;  // reflectance of the front face
uniform vec3 u_rho_rb;  // reflectance of the back face
uniform vec3 u_rho_tf;  // transmittance, light entering the front face
uniform vec3 u_rho_tb;  // transmittance, light entering the back face
uniform float u_specular;   // rho_s of wang2005 eq. (7)
uniform float u_roughness;  // m of wang2005 eq. (7)
#else
uniform vec3 u_albedo;  // Lambertian reflectance of wood or ground
#endif

in vec3 v_world;
flat in vec3 v_normal;
in vec2 v_sky;
#ifdef HAS_INDIRECT
in vec3 v_indirect_front;
in vec3 v_indirect_back;
#endif

layout(location = 0) out vec4 out_radiance;
layout(location = 1) out float out_tree;

#if defined(LEAF)
// wang2005 eq. (7): glossy reflection of the rough leaf surface (Cook-Torrance with the
// Beckmann distribution; Fresnel and geometric attenuation merged into rho_s):
//   f_s = rho_s / (cos_i cos_r cos^4 alpha) * exp(-tan^2 alpha / m^2) / (4 pi m^2).
// Returned as radiance per unit sun irradiance, f_s cos_i. cos_r is kept >= 0.2: without
// the (merged) shadowing term the 1/cos_r factor would blow up at grazing view.
float glossy(vec3 n, vec3 l, vec3 v) {
    vec3 h = normalize(l + v);
    float cos_a = max(dot(n, h), 1e-4);
    float cos2 = cos_a * cos_a;
    float tan2 = (1.0 - cos2) / cos2;
    float m2 = u_roughness * u_roughness;
    float cos_r = max(dot(n, v), 0.2);
    return u_specular * exp(-tan2 / m2) / (4.0 * PI * m2 * cos2 * cos2 * cos_r);
}
#endif

void main() {
    vec3 v = view_vector(v_world);
    vec3 front = normalize(v_normal);  // N_P: the front face's normal
    bool front_seen = dot(front, v) >= 0.0;
    vec3 n = front_seen ? front : -front;  // the side of the surface the camera sees
    float sky_near = front_seen ? v_sky.x : v_sky.y;  // open sky seen by the seen face ...
    float sky_far = front_seen ? v_sky.y : v_sky.x;   // ... and by the other face
    float cos_sun = dot(n, u_sun_dir);
    vec3 radiance;
#if defined(LEAF)
    // boulanger2008 eq. (5.4): seen from the front, F = rho_rf/pi M(N.w) + rho_tb/pi M(-N.w);
    // seen from the back, F = rho_tf/pi M(N.w) + rho_rb/pi M(-N.w). With n the seen side,
    // light on the seen side is reflected by that face; light from the far side is
    // transmitted after entering the far face.
    vec3 rho_r = front_seen ? u_rho_rf : u_rho_rb;
    vec3 rho_t = front_seen ? u_rho_tb : u_rho_tf;
    vec3 sun_side = cos_sun >= 0.0 ? n : -n;
    vec3 sun = u_sun_irradiance * sun_visibility(v_world, sun_side);  // unshadowed: u_sun_irradiance
    vec3 e_sun = sun * abs(cos_sun);
    if (cos_sun >= 0.0) {
        // wang2005 sec. 3: diffuse reflection rho_d / pi plus the glossy lobe, eq. (7)
        radiance = rho_r / PI * e_sun + glossy(n, u_sun_dir, v) * sun;
    } else {
        // wang2005 sec. 3: the BTDF is diffuse, rho_t / pi
        radiance = rho_t / PI * e_sun;
    }
    // The sky and the ground reach both faces: eq. (5.4) applied to each hemisphere.
    radiance += (rho_r * sky_irradiance(n, sky_near) + rho_t * sky_irradiance(-n, sky_far)) / PI;
#ifdef HAS_INDIRECT
    // eq. (5.4) on the scattered irradiance of each face (Algorithm 13's rho_f, rho_b): the
    // seen face reflects what reaches it and transmits what reaches the other face. Baked
    // methods give half of E_scattered to each face (scene.vert.glsl).
    vec3 e_near = max(front_seen ? v_indirect_front : v_indirect_back, vec3(0.0));
    vec3 e_far = max(front_seen ? v_indirect_back : v_indirect_front, vec3(0.0));
    radiance += (rho_r * e_near + rho_t * e_far) / PI;
#endif
    out_tree = 1.0;
#else
    // Opaque Lambertian: only the seen side is lit.
    float vis = cos_sun > 0.0 ? sun_visibility(v_world, n) : 0.0;
    radiance = u_albedo / PI * (u_sun_irradiance * vis * max(cos_sun, 0.0) + sky_irradiance(n, sky_near));
#if defined(WOOD)
    out_tree = 1.0;
#else
    out_tree = 0.0;
#endif
#endif
    out_radiance = vec4(radiance, 1.0);
}
