// jkatana interactive path: the shading, shared by mesh.frag (forward: one pass over the mesh)
// and deferred.frag (one full-screen pass over a G-buffer), included by BakedProgram._load.
//
// Shades the paper's blend (eq. 5) of hiraji (eq. 1) and hamon (eq. 2) under
// an environment, with tables baked by jkatana.interactive.bake from the JAX
// models (nothing here re-derives a model):
//   XYZ = sum_r A_r(cos θv, μ) · P_r(R; μ)
// with A = w A_hiraji(μ0) + (1 − w) A_hamon(μ1) and the environment read at
// the blended level w·ℓ(μ0) + (1 − w)·ℓ(μ1) (ℓ: log-spaced level index; exact
// where w is 0 or 1). P_r is a 3-D texture (u, v, level), so one trilinear
// fetch per basis function interpolates the μ levels too.
// A_r: lobe LUT (Fresnel low-rank coefficients × lobe energy × G), per model;
// P_r: environment projected on the spectral basis b_r and on the CIE 1931
// weights, prefiltered per μ level. Then XYZ → linear RGB (eq. 7, baked
// matrix) → transfer (eq. 8, baked table indexed by sqrt).
//
// Static switches (#define lines that BakedProgram._load inserts after #version; each combination
// is its own program): JK_SRGB (the transfer is sRGB: evaluated, not fetched), JK_RANK (1..4), JK_ROUGH (0: mirror-like, the narrowest μ
// level), JK_BLEND (0: hiraji everywhere), JK_TWO_TAP (the lobe's anisotropy:
// three binomial taps along the plane of incidence, prefiltered for the
// across-plane width, matching the lobe's in-plane mean and variance — moments
// baked from the models by jkatana.interactive.lobe_tables.lobe_lut; the name is
// historical: two extra taps; JK_TAPS = 5: four extra taps), JK_TAP_FIT (default: instead of the
// moment-matched binomial taps, three taps whose offsets, weights and filter width are fitted by least
// squares to the lobe's own kernel per (cos θv, μ) — filtered importance sampling (Křivánek & Colbert
// 2008) with a baked pattern; jkatana.interactive.taps.tap_fit; LUT layers 4–7; entries whose
// filter width the map does not resolve hold the moment pattern, taps.resolved_taps), JK_CAPS (0..4:
// compact bright sources split off the map as spherical caps, caps.sun_caps: each cap's radiance Q, weighted
// by the lobe table A, times the lobe's normalised kernel over the cap's disc, in closed form — one
// anisotropic Gaussian with the lobe's moments, jk_caps_xyz; its NumPy twin
// validation.shader_cap_rule.cap_response is tested against jkatana.light.capquad.cap_integral of the models),
// JK_CAP_TABLE (where a region holds a lobe other than the paper's: the caps through the bake's table of the
// cap integrated against each region's lobe, jkatana.interactive.captable, instead of the moments' Gaussian),
// JK_TAIL (with JK_TAP_FIT, where a region holds a long-tailed lobe: the number of tail taps, further reads at
// wider levels putting back the light of the lobe's tails that the three taps miss, jkatana.interactive.taps.tail_fit).

uniform vec3 cam_pos;
uniform sampler3D jk_env0;          // (u, v, level) → XYZ of basis function 0
#if JK_RANK > 1
uniform sampler3D jk_env1;
#endif
#if JK_RANK > 2
uniform sampler3D jk_env2;
#endif
#if JK_RANK > 3
uniform sampler3D jk_env3;
#endif
uniform sampler2DArray jk_lut;      // layer 0 hiraji, 1 hamon: rgba = A_0..A_3 (rank ≤ 2: A_0, A_1, first and
                                    // last tap weight); layers 2, 3: lobe shape of hiraji, hamon (rgb = log
                                    // across-width ratio, ± tap offset, mean offset); 4–7: fitted taps (below)
                                    // s: cos θv, t: μ level
uniform sampler2D jk_map;           // r = w, g = μ0, b = μ1
uniform sampler2D jk_transfer;      // 1 row: encode(s²)
uniform mat3 jk_xyz_to_rgb;
uniform mat3 jk_env_rot;
uniform float jk_exposure;
uniform float jk_log_mu_first;
uniform float jk_log_mu_step;
uniform float jk_n_levels;
uniform float jk_n_cos;
uniform float jk_n_transfer;

const float JK_PI = 3.14159265358979;

#if JK_CAPS > 0
uniform vec4 jk_cap[JK_CAPS];       // xyz: cap centre C (map frame), w: r² (r: the cap's angular radius)
uniform vec3 jk_cap_q[4 * JK_CAPS]; // [4k + r]: Q_r of cap k, Ω_cap Σ_λ b_r(λ) W(λ) L_cap(λ) (XYZ)

// XYZ of cap k reflected by lobe weights a on the spectral basis: Σ_r a_r Q_r
vec3 jk_cap_xyz(vec4 a, int k)
{
    vec3 q = a.x * jk_cap_q[4 * k];
#if JK_RANK > 1
    q += a.y * jk_cap_q[4 * k + 1];
#endif
#if JK_RANK > 2
    q += a.z * jk_cap_q[4 * k + 2];
#endif
#if JK_RANK > 3
    q += a.w * jk_cap_q[4 * k + 3];
#endif
    return q;
}

// The cap rule (NumPy twin: validation.shader_cap_rule.cap_response, tested against
// jkatana.light.capquad.cap_integral of the models). The reflected lobe is one anisotropic Gaussian on the sphere
// with the lobe's own first and second moments (lobe_tables.lobe_lut): centred on its mean direction, variance
// var_par along the plane of incidence and var_perp across it, in the prefilter kernel's form
// exp(−c h²)/cos h with h half the angle from the centre and c = 2/var per axis (the kernel of Walter et al.
// 2007 that the map levels are filtered with). The cap's disc is folded in per axis by keeping the kernel's
// exact value averaged over the disc at its centre, c' = 4 (1 − e^{−c r²/4})/r².

// c' of an axis of kernel constant c for cap k
float jk_cap_c(float c, int k)
{
    float r2 = jk_cap[k].w;
    float x = 0.25 * c * r2;
    return x < 1e-3 ? c * (1.0 - 0.5 * x) : 4.0 * (1.0 - exp(-x)) / r2;
}

// the normalised kernel at cap k, e = C_k − M, s2 = |e|²/4, for a lobe centred on M with in-plane axis tp and
// across-plane axis ty (unit, ⟂ M; zero vectors where cp = cy), constants cp ≤ cy (the disc folded in);
// 0 where cp h² > 30, a factor e⁻³⁰ below its peak
float jk_cap_gauss(vec3 e, float s2, vec3 tp, vec3 ty, float cp, float cy)
{
    if (cp * s2 > 30.0)                                    // sin²h ≤ h²
        return 0.0;
    float h = asin(sqrt(s2));
    float ep = dot(e, tp);
    float ey = dot(e, ty);
    float c = cp + (cy - cp) * ey * ey / max(ep * ep + ey * ey, 1e-30);  // cp where isotropic (tp = ty = 0)
    float cb = 2.0 * cp * cy / (cp + cy);
    float n = sqrt(cp * cy) / (4.0 * JK_PI * (1.0 - 1.0 / (6.0 * cb) + 1.0 / (60.0 * cb * cb)));
    return exp(-c * h * h) * inversesqrt(max(1.0 - s2, 1e-6)) * n;
}

// the caps' radiance for lobe coefficients a: centre M, axes tp, ty, kernel constants (c_par, c_perp) before
// the disc. A cap that the lobe cannot reach (c'_par s2 > 30 for certain, since c' ≥ c/(1 + c r²/4)) is
// skipped before any transcendental function, so blocks of pixels far from every cap cost a few products
vec3 jk_caps_xyz(vec4 a, vec3 M, vec3 tp, vec3 ty, vec2 c)
{
    vec3 xyz = vec3(0.0);
    for (int k = 0; k < JK_CAPS; ++k) {
        vec3 e = jk_cap[k].xyz - M;
        float s2 = min(0.25 * dot(e, e), 1.0);
        if (c.x * s2 > 30.0 * (1.0 + 0.25 * c.x * jk_cap[k].w))
            continue;
        float ks = jk_cap_gauss(e, s2, tp, ty, jk_cap_c(c.x, k), jk_cap_c(c.y, k));
        xyz += ks * jk_cap_xyz(a, k);
    }
    return xyz;
}
#endif

// Every table is sampled with textureLod(…, 0.0): none has mipmaps and minification and magnification
// filters are both linear, so the result is texture()'s, without the per-fragment derivatives and LOD
// that llvmpipe would otherwise compute for every fetch.

float level_of(float mu)
{
    return clamp((log(max(mu, 1e-6)) - jk_log_mu_first) / jk_log_mu_step, 0.0, jk_n_levels - 1.0);
}

vec4 lobe(float layer, float cv, float lvl)
{
    vec2 st = vec2((cv * (jk_n_cos - 1.0) + 0.5) / jk_n_cos, (lvl + 0.5) / jk_n_levels);
    return textureLod(jk_lut, vec3(st, layer), 0.0);
}

float encode1(float x)
{
#if JK_SRGB
    // the baked table is the IEC 61966-2-1 sRGB curve (BakedProgramCache checks): evaluated directly,
    // which llvmpipe does faster than the table fetch (bench_interactive), and without its interpolation
    float c = clamp(x, 0.0, 1.0);
    return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
#else
    float s = sqrt(clamp(x, 0.0, 1.0));
    return textureLod(jk_transfer, vec2((s * (jk_n_transfer - 1.0) + 0.5) / jk_n_transfer, 0.5), 0.0).r;
#endif
}

// the environment textures' coordinate (u, v, level) of direction d (map frame) at level coordinate lz
vec3 env_coord(vec3 d, float lz)
{
    return vec3(0.5 + atan(d.x, -d.z) / (2.0 * JK_PI), acos(clamp(d.y, -1.0, 1.0)) / JK_PI, lz);
}

// Σ_{r ≥ 1} a_r P_r(p): the basis functions after the first at texture coordinate p
vec3 env_rest(vec3 p, vec4 a)
{
    vec3 xyz = vec3(0.0);
#if JK_RANK > 1
    xyz += a.y * textureLod(jk_env1, p, 0.0).rgb;
#endif
#if JK_RANK > 2
    xyz += a.z * textureLod(jk_env2, p, 0.0).rgb;
#endif
#if JK_RANK > 3
    xyz += a.w * textureLod(jk_env3, p, 0.0).rgb;
#endif
    return xyz;
}

vec3 env_xyz(vec3 d, float lz, vec4 a)
{
    vec3 p = env_coord(d, lz);
    return a.x * textureLod(jk_env0, p, 0.0).rgb + env_rest(p, a);
}

#if JK_CAPS > 0 && JK_CAP_TABLE
uniform sampler3D jk_capk;          // (s_u, s_v, (region · n_mu + level) · n_cos + cos row) → r = ln(μ² K̄)
uniform vec4 jk_capk_dims;          // n_u, n_v, n_cos, n_mu of the table
uniform float jk_capk_ext;          // its reach E in widths: û = ±E s_u², v̂ = E s_v²

// μ² K̄ of a region's lobe at integer level k, view cosine cv, offsets o = (û, v̂ ≥ 0) in widths
// (NumPy twin: jkatana.interactive.captable.table_kernel)
float jk_capk_at(float region, float k, float cv, vec2 o)
{
    vec2 s = sqrt(min(abs(o), vec2(jk_capk_ext)) / jk_capk_ext);
    float x = ((sign(o.x) * s.x + 1.0) * 0.5 * (jk_capk_dims.x - 1.0) + 0.5) / jk_capk_dims.x;
    float y = (s.y * (jk_capk_dims.y - 1.0) + 0.5) / jk_capk_dims.y;
    float z = ((region * jk_capk_dims.w + k) * jk_capk_dims.z + cv * (jk_capk_dims.z - 1.0) + 0.5)
              / (2.0 * jk_capk_dims.w * jk_capk_dims.z);
    return exp(textureLod(jk_capk, vec3(x, y, z), 0.0).r);
}

// K̄ (1/sr) of a region's lobe at fractional level l for a cap at angles uv from R: both levels read at the
// offsets in units of the pixel's own μ, their μ² K̄ blended and divided by μ²
float jk_capk_kernel(float region, float l, float cv, vec2 uv)
{
    float mu = exp(jk_log_mu_first + l * jk_log_mu_step);
    vec2 o = uv / mu;
    if (max(abs(o.x), o.y) > jk_capk_ext)
        return 0.0;
    float k0 = min(floor(l), jk_capk_dims.w - 2.0);
    return mix(jk_capk_at(region, k0, cv, o), jk_capk_at(region, k0 + 1.0, cv, o), l - k0) / (mu * mu);
}

// the caps' radiance through the kernel table: Σ_k Q_k · (w A_hiraji K̄_hiraji + (1 − w) A_hamon K̄_hamon), the
// cap at angles u = atan2(C·t, C·R) along the plane of incidence (t = tn, towards N) and v = atan2(|C·y|, C·R)
// across it. A cap beyond E widths of the wider lobe (|u|, |v| ≤ ∠(C, R)) is skipped before any fetch.
vec3 jk_caps_table_xyz(float w, float cv, float lf, float lt, vec3 R, vec3 tn)
{
    vec3 ty = cross(R, tn);
    float cmin = cos(min(jk_capk_ext * exp(jk_log_mu_first + max(lf, lt) * jk_log_mu_step), JK_PI));
    vec3 xyz = vec3(0.0);
    for (int k = 0; k < JK_CAPS; ++k) {
        vec3 C = jk_cap[k].xyz;
        float cr = dot(C, R);
        if (cr < cmin)
            continue;
        vec2 uv = vec2(atan(dot(C, tn), cr), atan(abs(dot(C, ty)), cr));
        vec4 a = w * jk_capk_kernel(0.0, lf, cv, uv) * lobe(0.0, cv, lf)
                 + (1.0 - w) * jk_capk_kernel(1.0, lt, cv, uv) * lobe(1.0, cv, lt);
        xyz += jk_cap_xyz(a, k);
    }
    return xyz;
}
#endif

// display-encoded RGBA of a surface point: unit normal N, unit direction to the eye Vd, map coordinates uv
vec4 jk_shade(vec3 N, vec3 Vd, vec2 uv)
{
    float cv = dot(N, Vd);
    vec3 xyz = vec3(0.0);
    if (cv > 0.0) {
        vec3 R0 = 2.0 * cv * N - Vd;
        vec3 R = jk_env_rot * R0;
        vec3 m = textureLod(jk_map, uv, 0.0).rgb;
#if JK_BLEND
        float w = m.r;
#else
        float w = 1.0;
#endif
#if JK_ROUGH
        float lf = level_of(m.g);
        float lt = level_of(m.b);
#else
        float lf = 0.0;
        float lt = 0.0;
#endif
        vec4 a = w * lobe(0.0, cv, lf) + (1.0 - w) * lobe(1.0, cv, lt);
#if JK_ROUGH && JK_TAP_FIT
        // fitted taps (jkatana.interactive.taps.tap_fit): x = log(μ_e/μ), yzw = offsets o_j along the
        // plane of incidence (rad, towards N); layers 6, 7: weights w_j
        vec4 tp = w * lobe(4.0, cv, lf) + (1.0 - w) * lobe(5.0, cv, lt);
#if JK_RANK > 2
        vec3 tw = w * lobe(6.0, cv, lf).rgb + (1.0 - w) * lobe(7.0, cv, lt).rgb;
#else
        // at rank ≤ 2 the first and last weights ride in the lobe table's unused channels (ShadingState.textures);
        // the weights sum to 1 (tap_fit normalises them), in every blend of the two lobes too
        vec3 tw = vec3(a.z, 1.0 - a.z - a.w, a.w);
#endif
        float le = clamp(mix(lt, lf, w) + tp.x / jk_log_mu_step, 0.0, jk_n_levels - 1.0);
#elif JK_ROUGH
        vec3 shape = w * lobe(2.0, cv, lf).rgb + (1.0 - w) * lobe(3.0, cv, lt).rgb;
        float le = clamp(mix(lt, lf, w) + shape.r / jk_log_mu_step, 0.0, jk_n_levels - 1.0);
#else
        float le = 0.0;
#endif
        float lz = (le + 0.5) / jk_n_levels;
#if JK_ROUGH && (JK_TWO_TAP || JK_CAPS > 0)
        vec3 tn = N - dot(N, R0) * R0;                      // in the plane of incidence, ⟂ R, towards N
        tn = jk_env_rot * (tn / max(length(tn), 1e-6));
#endif
#if JK_TWO_TAP && JK_TAP_FIT
        // three taps fitted to the lobe (offsets, weights, filter width): the lobe's skew too. The first basis
        // function (the mean reflectance spectrum: nearly all of the luminance) is read at the three taps; the
        // higher ones (small, smooth spectral corrections) at the middle tap only (the offsets are sorted),
        // with the taps' total weight 1 (an approximation: their anisotropic blur is dropped; bench_interactive
        // measures the ΔE2000 of every agreement view)
        vec3 p1 = env_coord(cos(tp.z) * R + sin(tp.z) * tn, lz);
        vec3 core = tw.x * textureLod(jk_env0, env_coord(cos(tp.y) * R + sin(tp.y) * tn, lz), 0.0).rgb
                    + tw.y * textureLod(jk_env0, p1, 0.0).rgb
                    + tw.z * textureLod(jk_env0, env_coord(cos(tp.w) * R + sin(tp.w) * tn, lz), 0.0).rgb;
#if JK_TAIL > 0
        // the tail taps of long-tailed lobes (jkatana.interactive.taps.tail_fit; layers 8 + 2t, 9 + 2t: log(μ_t/μ),
        // offset, weight w_t): the first basis function read once more per tail tap, at the tap's own, wider
        // level; (1 − Σ w_t) core + Σ w_t tail_t
        vec3 tails = vec3(0.0);
        float wt = 0.0;
        for (int t = 0; t < JK_TAIL; ++t) {
            float layer = 8.0 + 2.0 * float(t);
            vec3 tt = w * lobe(layer, cv, lf).rgb + (1.0 - w) * lobe(layer + 1.0, cv, lt).rgb;
            float lzt = (clamp(mix(lt, lf, w) + tt.x / jk_log_mu_step, 0.0, jk_n_levels - 1.0) + 0.5) / jk_n_levels;
            tails += tt.z * textureLod(jk_env0, env_coord(cos(tt.y) * R + sin(tt.y) * tn, lzt), 0.0).rgb;
            wt += tt.z;
        }
        core = (1.0 - wt) * core + tails;
#endif
        xyz = a.x * core + env_rest(p1, a);
#elif JK_TWO_TAP && JK_TAPS == 5
        // five binomial taps (1, 4, 6, 4, 1)/16 at mean, mean ± spread, mean ± 2·spread: the lobe's mean and
        // variance, a kernel closer to the lobe's own shape than three taps
        float off = shape.g;
        vec3 Rc = cos(shape.b) * R + sin(shape.b) * tn;
        vec3 Ra = cos(shape.b + off) * R + sin(shape.b + off) * tn;
        vec3 Rb = cos(shape.b - off) * R + sin(shape.b - off) * tn;
        vec3 Rd = cos(shape.b + 2.0 * off) * R + sin(shape.b + 2.0 * off) * tn;
        vec3 Re = cos(shape.b - 2.0 * off) * R + sin(shape.b - 2.0 * off) * tn;
        xyz = 0.375 * env_xyz(Rc, lz, a) + 0.25 * (env_xyz(Ra, lz, a) + env_xyz(Rb, lz, a))
            + 0.0625 * (env_xyz(Rd, lz, a) + env_xyz(Re, lz, a));
#elif JK_TWO_TAP
        // three binomial taps (1/4, 1/2, 1/4) along the plane of incidence at mean, mean ± √2·spread:
        // the in-plane variance of the sum is var_perp + spread² = var_par (the lobe's)
        float off = 1.41421356 * shape.g;
        vec3 Rc = cos(shape.b) * R + sin(shape.b) * tn;
        vec3 Ra = cos(shape.b + off) * R + sin(shape.b + off) * tn;
        vec3 Rb = cos(shape.b - off) * R + sin(shape.b - off) * tn;
        xyz = 0.5 * env_xyz(Rc, lz, a) + 0.25 * (env_xyz(Ra, lz, a) + env_xyz(Rb, lz, a));
#else
        xyz = env_xyz(R, lz, a);
#endif
#if JK_CAPS > 0 && JK_ROUGH && JK_CAP_TABLE
        // the caps through the kernel table of the regions' lobes (jk_caps_table_xyz)
        xyz += jk_caps_table_xyz(w, cv, lf, lt, R, tn);
#elif JK_CAPS > 0 && JK_ROUGH
        // the caps through the lobe's moments (jk_caps_xyz): centre at the mean offset, across-plane
        // variance 2 μ_e²/ln2 of the moment pattern's level (c = 2/var = ln2/μ_e²), in-plane var + spread²
#if JK_TAP_FIT
        vec3 shape = w * lobe(2.0, cv, lf).rgb + (1.0 - w) * lobe(3.0, cv, lt).rgb;
        float lm = clamp(mix(lt, lf, w) + shape.r / jk_log_mu_step, 0.0, jk_n_levels - 1.0);
#else
        float lm = le;
#endif
        float c_perp = 0.69314718 * exp(-2.0 * (jk_log_mu_first + lm * jk_log_mu_step));
        float c_par = c_perp / (1.0 + 0.5 * c_perp * shape.g * shape.g);
        vec3 M = cos(shape.b) * R + sin(shape.b) * tn;
        xyz += jk_caps_xyz(a, M, cos(shape.b) * tn - sin(shape.b) * R, cross(R, tn), vec2(c_par, c_perp));
#elif JK_CAPS > 0
        // mirror-like: isotropic, the narrowest level's width about R
        xyz += jk_caps_xyz(a, R, vec3(0.0), vec3(0.0), vec2(0.69314718 * exp(-2.0 * jk_log_mu_first)));
#endif
    }
    vec3 rgb = jk_xyz_to_rgb * (xyz * jk_exposure);
    return vec4(encode1(rgb.r), encode1(rgb.g), encode1(rgb.b), 1.0);
}
