// Boulanger's per-leaf tree lighting, evaluated per vertex (boulanger2008 ch. 5, sec. 5.6,
// Algorithms 8-14). Mirrors foliage_tools/lighting/envelope/boulanger.py function by function, and
// returns irradiance on the leaf's front and back faces, as the Python model does; the
// fragment shader turns it into radiance with eq. (5.4) (Algorithm 10's rho_f, rho_b).
//
// Per leaf: s_max(P, w_j) toward the 8 directions of eq. (5.28), stored as two vec4 per
// vertex ("two 4D vectors per vertex", sec. 5.6). Per tree (prototype): tau and the
// directions w_j in the prototype's frame. Per instance: the sun direction in the
// prototype's frame (the instance's world_from_proto may rotate the tree, so the sun
// the leaves see in their own frame differs per instance; eqs. (5.7)-(5.33) are written
// in the tree's frame). A, rho with A rho = 2 tau (eq. (5.5)), so only tau enters.

const float BOULANGER_PI = 3.14159265358979;
const float BIN_SOLID_ANGLE = 4.0 * BOULANGER_PI / 8.0;  // Omega_j = 4 pi / N_dir, eq. (5.1)

uniform vec3 u_omega[8];   // eq. (5.28): the sample directions w_j in the prototype's frame
uniform float u_tau;       // the tree's optical thickness (foliage:tau), 1 / stage unit
uniform vec3 u_sm_rho_r;   // rho_rf + rho_rb (eq. (5.19): rho_bar = rho_r + rho_t)
uniform vec3 u_sm_rho_t;   // rho_tf + rho_tb

// s_max(P, w_j) of the leaf, j = 0..7
float smax_at(vec4 s0, vec4 s1, int j) {
    return j < 4 ? s0[j] : s1[j - 4];
}

// M(w_l . w_j) of eq. (5.31); their sum is >= 4/sqrt(6) for the cube diagonals of
// eq. (5.28), so the normalisation below never divides by zero.
void direction_weights(vec3 light, out float w[8], out float total) {
    total = 0.0;
    for (int j = 0; j < 8; ++j) {
        w[j] = max(dot(u_omega[j], light), 0.0);
        total += w[j];
    }
}

// s~_max(P, w_l) of eq. (5.7) (Algorithm 12, sMaxL): the cosine-lobe blend of the 8 s_max.
float interpolated_smax(vec4 s0, vec4 s1, float w[8], float total) {
    return (dot(s0, vec4(w[0], w[1], w[2], w[3])) + dot(s1, vec4(w[4], w[5], w[6], w[7]))) / total;
}

// phi(x) = (1 - e^-x) / x, -> 1 at x = 0 (the finite form of eq. (5.24) as G3 -> 0).
// Below 0.05 the Taylor series to x^4 (error < x^5 / 720 < 5e-10); above it the
// cancellation in 1 - e^-x costs at most ~1e-6 relative in float32.
float relative_expm1(float x) {
    if (abs(x) < 0.05) {
        return 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x / 120.0)));
    }
    return (1.0 - exp(-x)) / x;
}

// eqs. (B.5), (B.6): averages over uniform leaf normals for two directions at angle alpha,
// from c = cos(alpha): Av_t = ((pi - a) c + s) / (6 pi), Av_r = (s - a c) / (6 pi).
float av_t(float c) {
    c = clamp(c, -1.0, 1.0);
    float a = acos(c);
    return ((BOULANGER_PI - a) * c + sqrt(max(1.0 - c * c, 0.0))) / (6.0 * BOULANGER_PI);
}
float av_r(float c) {
    c = clamp(c, -1.0, 1.0);
    float a = acos(c);
    return (sqrt(max(1.0 - c * c, 0.0)) - a * c) / (6.0 * BOULANGER_PI);
}

// Algorithm 12, eq. (5.8) without F: unit-sun irradiance of the front (x) and back (y)
// face, E_front = M(N.w_l) e^{-tau s~_max}, E_back = M(-N.w_l) e^{-tau s~_max}.
vec2 smax_sun_direct(vec3 n, vec4 s0, vec4 s1, vec3 light) {
    float w[8];
    float total;
    direction_weights(light, w, total);
    float att = exp(-u_tau * interpolated_smax(s0, s1, w, total));
    float c = dot(n, light);
    return vec2(max(c, 0.0), max(-c, 0.0)) * att;
}

// Algorithm 13: unit-sun irradiance of the front and back face from one bounce on the
// neighbouring leaves, eq. (5.11) with L_o_sample of eq. (5.24):
//   A L_o_sample(j) = A G1(j) e^{-G2 sum_j' M(w_l.w_j') s_max(j')} (1 - e^{-G3(j) s_j}) / G3(j)
//                   = A G1(j) e^{-tau s~_max} s_j phi(G3(j) s_j)        (G2 of eq. (5.25))
// with A G1 = 2 tau (4 / N_dir)(rho_r Av_r + rho_t Av_t) (eq. (5.18) via (B.5)-(B.6)) and
// G3(j) = tau (1 - sum_j' M(w_l.w_j')(w_j.w_j') / sum_j' M(w_l.w_j')) (eq. (5.26)).
// The thesis precomputes G1/G3 per tree (eq. (5.33)); the sun differs per instance here,
// so they are computed per vertex, and G1 and s phi(G3 s) are kept apart (no 0/0).
void smax_sun_indirect(vec3 n, vec4 s0, vec4 s1, vec3 light, out vec3 front, out vec3 back) {
    float w[8];
    float total;
    direction_weights(light, w, total);
    float att = exp(-u_tau * interpolated_smax(s0, s1, w, total));
    front = vec3(0.0);
    back = vec3(0.0);
    for (int j = 0; j < 8; ++j) {
        float mean_cos = 0.0;  // sum_j' M(w_l.w_j')(w_j.w_j') / sum_j' M(w_l.w_j')
        for (int k = 0; k < 8; ++k) {
            mean_cos += w[k] * dot(u_omega[j], u_omega[k]);
        }
        float g3 = u_tau * (1.0 - mean_cos / total);
        float c_l = dot(u_omega[j], light);  // cos(alpha) between w_j and w_l
        vec3 area_g1 = 2.0 * u_tau * 4.0 / 8.0 * (u_sm_rho_r * av_r(c_l) + u_sm_rho_t * av_t(c_l));
        float s = smax_at(s0, s1, j);
        vec3 sample_j = area_g1 * (att * s * relative_expm1(g3 * s));
        float c = dot(n, u_omega[j]);
        front += max(c, 0.0) * sample_j;
        back += max(-c, 0.0) * sample_j;
    }
}

// Algorithm 11, eq. (5.6) without F: sky and ground irradiance of the front and back face,
// E_front = (4 pi / N_dir) sum_j M(N.w_j) e^{-tau s_max(j)} L_sky(w_j) (attenuation of
// eq. (5.30), radiance per direction of eq. (5.29) given in radiance[j]).
void smax_sky(vec3 n, vec4 s0, vec4 s1, vec3 radiance[8], out vec3 front, out vec3 back) {
    front = vec3(0.0);
    back = vec3(0.0);
    for (int j = 0; j < 8; ++j) {
        vec3 incoming = exp(-u_tau * smax_at(s0, s1, j)) * radiance[j];
        float c = dot(n, u_omega[j]);
        front += max(c, 0.0) * incoming;
        back += max(-c, 0.0) * incoming;
    }
    front *= BIN_SOLID_ANGLE;
    back *= BIN_SOLID_ANGLE;
}
