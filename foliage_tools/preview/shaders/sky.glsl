// Sky visibility from depth maps of the trees along directions spread over the sky.

#define MAX_SKY 16
uniform int u_sky_count;                      // 0: the sky is not occluded
uniform vec3 u_sky_dir[MAX_SKY];              // unit directions toward the sky, even in solid angle
uniform mat4 u_sky_view_projection[MAX_SKY];  // orthographic depth map of the tree along each
uniform sampler2DShadow u_sky_map;            // the depth maps, tiled u_sky_tiles x u_sky_tiles
uniform int u_sky_tiles;
uniform float u_sky_texel;                    // 1 / tile size
uniform float u_sky_texel_world;
uniform float u_sky_depth_bias;

// Cosine-weighted fraction of the sky directions above the surface (unit normal n, on the
// side the light arrives from) that the trees do not block at p:
//   V(p, n) = sum_k max(n.w_k, 0) vis_k(p) / sum_k max(n.w_k, 0).
// The directions sample the sky evenly in solid angle, so this estimates the open share
// of the sky irradiance integral; a normal offset of 1.5 texels, as for the sun, keeps a
// leaf from occluding itself. Evaluated per vertex: sky light varies slowly over a surface,
// and per fragment the 16 lookups cost several times the rest of the shading on llvmpipe.
float sky_visibility(vec3 p, vec3 n) {
    float seen = 0.0;
    float total = 0.0;
    vec3 q = p + n * u_sky_texel_world * 1.5;
    for (int k = 0; k < u_sky_count; ++k) {
        float c = dot(n, u_sky_dir[k]);
        if (c <= 0.0) {
            continue;
        }
        vec4 clip = u_sky_view_projection[k] * vec4(q, 1.0);
        vec3 s = clip.xyz / clip.w * 0.5 + 0.5;
        float vis = 1.0;  // outside the map: nothing of the tree lies that way
        if (s.x >= 0.0 && s.x <= 1.0 && s.y >= 0.0 && s.y <= 1.0) {
            vec2 tile = vec2(float(k % u_sky_tiles), float(k / u_sky_tiles));
            vec2 uv = (tile + clamp(s.xy, u_sky_texel, 1.0 - u_sky_texel)) / float(u_sky_tiles);
            vis = textureLod(u_sky_map, vec3(uv, s.z - u_sky_depth_bias), 0.0);
        }
        seen += c * vis;
        total += c;
    }
    return total > 0.0 ? seen / total : 1.0;
}
