// Light arriving at a surface point: sun (shadow-mapped), sky and ground bounce.
// Radiometry (DESIGN.md section 3): the sun delivers irradiance u_sun_irradiance on a
// plane perpendicular to it; the sky is a uniform radiance over the upper hemisphere.

const float PI = 3.14159265358979;

uniform vec3 u_sun_dir;          // unit vector toward the sun
uniform vec3 u_sun_irradiance;   // RGB; zero when the sun is below the ground
uniform vec3 u_sky_radiance;     // uniform radiance of the upper hemisphere
uniform vec3 u_ground_radiance;  // uniform radiance of the lower hemisphere (ground bounce, 0 without ground)
uniform vec3 u_up;

uniform vec3 u_camera_pos;
uniform vec3 u_view_dir;         // camera forward, for orthographic cameras
uniform bool u_orthographic;

uniform sampler2DShadow u_shadow_map;
uniform mat4 u_light_view_projection;
uniform float u_shadow_texel_world;  // world size of one shadow-map texel
uniform float u_shadow_texel;        // 1 / shadow-map size
uniform float u_shadow_depth_bias;   // in shadow-map depth units [0, 1]

// Irradiance on a surface with unit normal n from a uniform sky above the horizon and a
// uniform ground below it: integrating L cos(theta) over the part of each hemisphere that
// the surface sees gives pi L (1 + n.up) / 2 from the sky and pi L_g (1 - n.up) / 2 from
// the ground (exact for an infinite horizontal ground). The sky part is scaled by the
// fraction of it the trees leave open (sky_visibility in sky.glsl, 1 when not occluded);
// the ground bounce is not occluded.
vec3 sky_irradiance(vec3 n, float visibility) {
    float c = dot(n, u_up);
    return PI * (u_sky_radiance * (0.5 + 0.5 * c) * visibility + u_ground_radiance * (0.5 - 0.5 * c));
}

// Unit vector from the surface point toward the viewer.
vec3 view_vector(vec3 p) {
    return u_orthographic ? -u_view_dir : normalize(u_camera_pos - p);
}

// Fraction of the sun visible from p, for a surface whose sun-facing side has unit normal n.
// Normal-offset shadow mapping: the lookup point moves toward the light along n by about a
// texel (more at grazing sun), so a thin leaf card - drawn with both faces in the shadow
// map - never shadows itself on either face, and lit surfaces do not show acne.
// Percentage-closer filtering: four hardware-filtered (2x2 texel) comparisons at half-texel
// offsets, a tent filter over 3x3 texels for the price of four lookups.
float sun_visibility(vec3 p, vec3 n) {
    float cos_l = clamp(dot(n, u_sun_dir), 0.0, 1.0);
    vec3 q = p + n * u_shadow_texel_world * (1.5 + 2.0 * (1.0 - cos_l));
    vec4 c = u_light_view_projection * vec4(q, 1.0);
    vec3 s = c.xyz / c.w * 0.5 + 0.5;
    if (s.x < 0.0 || s.x > 1.0 || s.y < 0.0 || s.y > 1.0) {
        return 1.0;  // outside the map: nothing that casts shadows lies toward the sun
    }
    float ref = s.z - u_shadow_depth_bias;
    float h = 0.5 * u_shadow_texel;
    float lit = texture(u_shadow_map, vec3(s.xy + vec2(-h, -h), ref)) + texture(u_shadow_map, vec3(s.xy + vec2(h, -h), ref))
              + texture(u_shadow_map, vec3(s.xy + vec2(-h, h), ref)) + texture(u_shadow_map, vec3(s.xy + vec2(h, h), ref));
    return 0.25 * lit;
}

