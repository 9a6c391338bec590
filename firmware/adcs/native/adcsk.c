// adcsk: the lean ADCS filters' hot kernels as a MicroPython native module (natmod, `make natmod`).
//
// Each function here is the Python function of the same name (less a leading underscore; phi9 is apkf_lean.phi,
// update_rows LeanStkf._update_rows) in firmware/adcs/linalg.py, stkf_kernels.py, stkf_lean.py or apkf_lean.py,
// over the same buffers: the same operations in the same order, each value stored
// to a buffer rounded to that buffer's type (array 'f' or 'd') and read back where the Python reads it back, so the
// results are equal bit for bit (tests/test_adcs_natmod.py; built with -ffp-contract=off: no fused
// multiply-add). The Python forms stay the reference and run wherever the module is not built (CPython, or a
// port without native modules). Only the arithmetic moves: no float is boxed, so a call allocates nothing.

#if !defined(ADCSK_BUILTIN) && !defined(ADCSK_CPYTHON)
#include "py/dynruntime.h"
#endif
// ADCSK_BUILTIN: compiled into a firmware image as a built-in module ``adcsk`` (a board's, ground/pil_build.py),
// with its own runtime.h and libm-free sqrt (the FPU's instruction, -fno-math-errno); ADCSK_CPYTHON: into the
// CPython extension (adcsk_cpython.c, which gives the MicroPython calls used here over CPython's)

#if defined(__arm__) && !defined(ADCSK_BUILTIN)
// newlib's sqrt wrapper pulls in data a native module cannot hold; its IEEE core is the same correctly
// rounded square root (as every IEEE sqrt, x64's sqrtsd included)
extern double __ieee754_sqrt(double);
#define SQRT(x) __ieee754_sqrt(x)
#else
#define SQRT(x) __builtin_sqrt(x)
#endif

typedef struct {
    void *p;
    size_t n;
    char tc;
} vec_t;

// a float buffer (array 'f' or 'd') of at least n elements
static vec_t vec(mp_obj_t o, size_t n) {
    mp_buffer_info_t bi;
    mp_get_buffer_raise(o, &bi, MP_BUFFER_RW);
    vec_t v;
    v.p = bi.buf;
    v.tc = (char)bi.typecode;
    if (v.tc == 'f') {
        v.n = bi.len / sizeof(float);
    } else if (v.tc == 'd') {
        v.n = bi.len / sizeof(double);
    } else {
        mp_raise_TypeError(MP_ERROR_TEXT("adcsk: a float array ('f' or 'd') is needed"));
    }
    if (v.n < n) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk: buffer too short"));
    }
    return v;
}

static inline double rd(const vec_t *v, size_t i) {
    return v->tc == 'f' ? (double)((float *)v->p)[i] : ((double *)v->p)[i];
}

static inline void wr(vec_t *v, size_t i, double x) {
    if (v->tc == 'f') {
        ((float *)v->p)[i] = (float)x;
    } else {
        ((double *)v->p)[i] = x;
    }
}

// n values of a float buffer, or of a list/tuple of floats, into out (the values a Python read gives)
static void vals(mp_obj_t o, double *out, size_t n) {
    if (mp_obj_is_type(o, &mp_type_list) || mp_obj_is_type(o, &mp_type_tuple)) {
        size_t len;
        mp_obj_t *items;
        mp_obj_get_array(o, &len, &items);
        if (len < n) {
            mp_raise_ValueError(MP_ERROR_TEXT("adcsk: list too short"));
        }
        for (size_t i = 0; i < n; i++) {
            out[i] = mp_obj_get_float_to_d(items[i]);
        }
        return;
    }
    vec_t v = vec(o, n);
    for (size_t i = 0; i < n; i++) {
        out[i] = rd(&v, i);
    }
}

static size_t sz(mp_obj_t o) {
    mp_int_t i = mp_obj_get_int(o);
    if (i < 0) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk: negative size"));
    }
    return (size_t)i;
}

// ---- linalg.py --------------------------------------------------------------------------------------------

// matmul(C, A, B, n, m, p): C (n x p) = A (n x m) B; m == 6 sums from the first product, else from 0.0
static void k_matmul(vec_t *C, const vec_t *A, const vec_t *B, size_t n, size_t m, size_t p) {
    for (size_t i = 0; i < n; i++) {
        for (size_t j = 0; j < p; j++) {
            double s;
            size_t k0 = 0;
            if (m == 6) {
                s = rd(A, i * m) * rd(B, j);
                k0 = 1;
            } else {
                s = 0.0;
            }
            for (size_t k = k0; k < m; k++) {
                s = s + rd(A, i * m + k) * rd(B, k * p + j);
            }
            wr(C, i * p + j, s);
        }
    }
}

static mp_obj_t matmul(size_t n_args, const mp_obj_t *args) {
    size_t n = sz(args[3]), m = sz(args[4]), p = sz(args[5]);
    vec_t C = vec(args[0], n * p), A = vec(args[1], n * m), B = vec(args[2], m * p);
    k_matmul(&C, &A, &B, n, m, p);
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(matmul_obj, 6, 6, matmul);

// matmul_bt(C, A, B, n, m, p): C (n x p) = A (n x m) B^T
static mp_obj_t matmul_bt(size_t n_args, const mp_obj_t *args) {
    size_t n = sz(args[3]), m = sz(args[4]), p = sz(args[5]);
    vec_t C = vec(args[0], n * p), A = vec(args[1], n * m), B = vec(args[2], p * m);
    for (size_t i = 0; i < n; i++) {
        for (size_t j = 0; j < p; j++) {
            double s;
            size_t k0 = 0;
            if (m == 6) {
                s = rd(&A, i * m) * rd(&B, j * m);
                k0 = 1;
            } else {
                s = 0.0;
            }
            for (size_t k = k0; k < m; k++) {
                s = s + rd(&A, i * m + k) * rd(&B, j * m + k);
            }
            wr(&C, i * p + j, s);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(matmul_bt_obj, 6, 6, matmul_bt);

// symmetrize(P, n)
static mp_obj_t symmetrize(mp_obj_t P_in, mp_obj_t n_in) {
    size_t n = sz(n_in);
    vec_t P = vec(P_in, n * n);
    for (size_t i = 0; i < n; i++) {
        for (size_t j = i + 1; j < n; j++) {
            double v = 0.5 * (rd(&P, i * n + j) + rd(&P, j * n + i));
            wr(&P, i * n + j, v);
            wr(&P, j * n + i, v);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_2(symmetrize_obj, symmetrize);

// cholesky(L, A, n) (linalg._cholesky_loops; the n = 3 form equals it)
static bool k_cholesky(vec_t *L, const vec_t *A, size_t n) {
    for (size_t i = 0; i < n * n; i++) {
        wr(L, i, 0.0);
    }
    for (size_t j = 0; j < n; j++) {
        double s = rd(A, j * n + j);
        for (size_t k = 0; k < j; k++) {
            s = s - rd(L, j * n + k) * rd(L, j * n + k);
        }
        if (!(s > 0.0)) {
            return false;
        }
        double d = SQRT(s);
        wr(L, j * n + j, d);
        for (size_t i = j + 1; i < n; i++) {
            s = rd(A, i * n + j);
            for (size_t k = 0; k < j; k++) {
                s = s - rd(L, i * n + k) * rd(L, j * n + k);
            }
            wr(L, i * n + j, s / d);
        }
    }
    return true;
}

static mp_obj_t cholesky(mp_obj_t L_in, mp_obj_t A_in, mp_obj_t n_in) {
    size_t n = sz(n_in);
    vec_t L = vec(L_in, n * n), A = vec(A_in, n * n);
    return mp_obj_new_bool(k_cholesky(&L, &A, n));
}
static MP_DEFINE_CONST_FUN_OBJ_3(cholesky_obj, cholesky);

// chol_solve_rows(X, L, B, n, m): X (m x n) = B S^-1, S = L L^T; X may alias B
static mp_obj_t chol_solve_rows(size_t n_args, const mp_obj_t *args) {
    size_t n = sz(args[3]), m = sz(args[4]);
    vec_t X = vec(args[0], m * n), L = vec(args[1], n * n), B = vec(args[2], m * n);
    for (size_t r = 0; r < m; r++) {
        size_t o = r * n;
        for (size_t i = 0; i < n; i++) {
            double s = rd(&B, o + i);
            for (size_t k = 0; k < i; k++) {
                s = s - rd(&L, i * n + k) * rd(&X, o + k);
            }
            wr(&X, o + i, s / rd(&L, i * n + i));
        }
        for (size_t i = n; i-- > 0;) {
            double s = rd(&X, o + i);
            for (size_t k = i + 1; k < n; k++) {
                s = s - rd(&L, k * n + i) * rd(&X, o + k);
            }
            wr(&X, o + i, s / rd(&L, i * n + i));
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(chol_solve_rows_obj, 5, 5, chol_solve_rows);

// joseph_select(P, n, r0, m, R, Kt, L, W, RK) (linalg.py: the S, Cholesky, _solve_cols and _joseph_loops
// steps; the m = 3 and 6 written-out forms equal them)
static mp_obj_t joseph_select(size_t n_args, const mp_obj_t *args) {
    size_t n = sz(args[1]), r0 = sz(args[2]), m = sz(args[3]);
    if (r0 + m > n || m > 6) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.joseph_select: rows out of range"));
    }
    double rv[36];                                   // R: a float buffer or a list (read only)
    vals(args[4], rv, m * m);
    vec_t R = {rv, m * m, 'd'};
    vec_t P = vec(args[0], n * n), Kt = vec(args[5], m * n), L = vec(args[6], m * m);
    vec_t W = vec(args[7], n * n), RK = vec(args[8], m * n);
    for (size_t i = 0; i < m; i++) {
        for (size_t j = 0; j < m; j++) {
            wr(&W, i * m + j, rd(&P, (r0 + i) * n + r0 + j) + rd(&R, i * m + j));
        }
    }
    if (!k_cholesky(&L, &W, m)) {
        return mp_const_false;
    }
    for (size_t i = 0; i < m * n; i++) {             // Kt = P[r0:r0+m, :]
        wr(&Kt, i, rd(&P, r0 * n + i));
    }
    for (size_t c = 0; c < n; c++) {                 // _solve_cols: Kt = S^-1 Kt, column by column
        for (size_t i = 0; i < m; i++) {
            double s = rd(&Kt, i * n + c);
            for (size_t k = 0; k < i; k++) {
                s = s - rd(&L, i * m + k) * rd(&Kt, k * n + c);
            }
            wr(&Kt, i * n + c, s / rd(&L, i * m + i));
        }
        for (size_t i = m; i-- > 0;) {
            double s = rd(&Kt, i * n + c);
            for (size_t k = i + 1; k < m; k++) {
                s = s - rd(&L, k * m + i) * rd(&Kt, k * n + c);
            }
            wr(&Kt, i * n + c, s / rd(&L, i * m + i));
        }
    }
    // A = P - K P[r0:, :] into W (P's rows r0.. are read before any write: P is not written here)
    for (size_t i = 0; i < n; i++) {
        for (size_t j = 0; j < n; j++) {
            double s = rd(&P, i * n + j);
            for (size_t k = 0; k < m; k++) {
                s = s - rd(&Kt, k * n + i) * rd(&P, (r0 + k) * n + j);
            }
            wr(&W, i * n + j, s);
        }
    }
    k_matmul(&RK, &R, &Kt, m, m, n);                 // R K^T
    for (size_t i = 0; i < n; i++) {                 // P+ = A - A[:, r0:] K^T + K R K^T, mirrored
        for (size_t j = i; j < n; j++) {
            double s = rd(&W, i * n + j);
            for (size_t k = 0; k < m; k++) {
                s = s + (rd(&Kt, k * n + i) * rd(&RK, k * n + j) - rd(&W, i * n + r0 + k) * rd(&Kt, k * n + j));
            }
            wr(&P, i * n + j, s);
            wr(&P, j * n + i, s);
        }
    }
    return mp_const_true;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(joseph_select_obj, 9, 9, joseph_select);

// ---- stkf_lean.py -----------------------------------------------------------------------------------------

// column c of rows 0..5 of P, then row c of columns 0..5, set to v (the Python forms' order of stores)
static void mirror6(vec_t *P, size_t ld, size_t c, const double *v) {
    for (int i = 0; i < 6; i++) {
        wr(P, i * ld + c, v[i]);
    }
    for (int i = 0; i < 6; i++) {
        wr(P, c * ld + i, v[i]);
    }
}

// P[r][c] = P[c][r] = x (row r's entry first, as the Python forms write them)
static inline void wr_sym(vec_t *P, size_t ld, size_t r, size_t c, double x) {
    wr(P, r * ld + c, x);
    wr(P, c * ld + r, x);
}

// rows_mul_mirror(P, ld, src, c_lo, c_hi, F)
static mp_obj_t rows_mul_mirror(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]), src = sz(args[2]), c_lo = sz(args[3]), c_hi = sz(args[4]);
    double f[36];
    vals(args[5], f, 36);
    vec_t P = vec(args[0], (src + 6) * ld);
    if (c_hi > ld || 6 > ld) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.rows_mul_mirror: columns out of range"));
    }
    size_t s = src * ld;
    for (size_t c = c_lo; c < c_hi; c++) {
        size_t b = s + c;
        double p[6], v[6];
        for (int k = 0; k < 6; k++) {
            p[k] = rd(&P, b + k * ld);
        }
        for (int i = 0; i < 6; i++) {
            const double *fi = f + 6 * i;
            v[i] = fi[0] * p[0] + fi[1] * p[1] + fi[2] * p[2] + fi[3] * p[3] + fi[4] * p[4] + fi[5] * p[5];
        }
        mirror6(&P, ld, c, v);
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(rows_mul_mirror_obj, 6, 6, rows_mul_mirror);

// sandwich(P, ld, r0, F, Q, T, src=None)
static mp_obj_t sandwich(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]), r0 = sz(args[2]);
    size_t src = (n_args > 6 && args[6] != mp_const_none) ? sz(args[6]) : r0;
    double f[36], q[36];
    vals(args[3], f, 36);
    vals(args[4], q, 36);
    size_t hi = (src > r0 ? src : r0) + 6;
    vec_t P = vec(args[0], hi * ld), T = vec(args[5], 36);
    size_t s = src * ld + src;
    for (size_t c = 0; c < 6; c++) {                 // T = F P, column by column
        size_t b = s + c;
        double p[6];
        for (int k = 0; k < 6; k++) {
            p[k] = rd(&P, b + k * ld);
        }
        for (int i = 0; i < 6; i++) {
            const double *fi = f + 6 * i;
            wr(&T, 6 * i + c, fi[0] * p[0] + fi[1] * p[1] + fi[2] * p[2] + fi[3] * p[3] + fi[4] * p[4] + fi[5] * p[5]);
        }
    }
    for (size_t i = 0; i < 6; i++) {
        size_t o = 6 * i;
        double t[6];
        for (int k = 0; k < 6; k++) {
            t[k] = rd(&T, o + k);
        }
        for (size_t j = i; j < 6; j++) {
            const double *g = f + 6 * j;
            double v = q[o + j] + t[0] * g[0] + t[1] * g[1] + t[2] * g[2] + t[3] * g[3] + t[4] * g[4] + t[5] * g[5];
            wr_sym(&P, ld, r0 + i, r0 + j, v);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(sandwich_obj, 6, 7, sandwich);

// column c of [G | 0; 0 I] P[0:6, :] (G 6 x 3 on the first three rows; rows 3-5 add P's own), into v
static void ikh_col(const vec_t *P, size_t ld, size_t c, const double *g, double *v) {
    double p0 = rd(P, c), p1 = rd(P, ld + c), p2 = rd(P, 2 * ld + c);
    v[0] = g[0] * p0 + g[1] * p1 + g[2] * p2;
    v[1] = g[3] * p0 + g[4] * p1 + g[5] * p2;
    v[2] = g[6] * p0 + g[7] * p1 + g[8] * p2;
    v[3] = g[9] * p0 + g[10] * p1 + g[11] * p2 + rd(P, 3 * ld + c);
    v[4] = g[12] * p0 + g[13] * p1 + g[14] * p2 + rd(P, 4 * ld + c);
    v[5] = g[15] * p0 + g[16] * p1 + g[17] * p2 + rd(P, 5 * ld + c);
}

// _ikh_rows(P, ld, c_lo, c_hi, G)
static mp_obj_t ikh_rows(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]), c_lo = sz(args[2]), c_hi = sz(args[3]);
    double g[18];
    vals(args[4], g, 18);
    if (c_hi > ld || 6 > ld) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk._ikh_rows: columns out of range"));
    }
    vec_t P = vec(args[0], 6 * ld);
    for (size_t c = c_lo; c < c_hi; c++) {
        double v[6];
        ikh_col(&P, ld, c, g, v);
        mirror6(&P, ld, c, v);
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(ikh_rows_obj, 5, 5, ikh_rows);

// _ikh_sandwich(P, ld, G, Q, T): T is work; the Python form's T is a list (doubles), as t here
static mp_obj_t ikh_sandwich(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]);
    double g[18], q[36], t[36];
    vals(args[2], g, 18);
    vals(args[3], q, 36);
    vec_t P = vec(args[0], 6 * ld);
    for (size_t c = 0; c < 6; c++) {
        double v[6];
        ikh_col(&P, ld, c, g, v);
        for (int k = 0; k < 6; k++) {
            t[6 * k + c] = v[k];
        }
    }
    for (size_t i = 0; i < 6; i++) {
        size_t o = 6 * i;
        double t0 = t[o], t1 = t[o + 1], t2 = t[o + 2];
        for (size_t j = i; j < 6; j++) {
            size_t k = 3 * j;
            double s = q[o + j] + t0 * g[k] + t1 * g[k + 1] + t2 * g[k + 2];
            if (j >= 3) {
                s = s + t[o + j];
            }
            wr_sym(&P, ld, i, j, s);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(ikh_sandwich_obj, 5, 5, ikh_sandwich);

// Hp: a list of 6 float buffers of at least m each, into H
static void rows6(mp_obj_t o, size_t m, vec_t *H) {
    size_t nrow;
    mp_obj_t *rows;
    mp_obj_get_array(o, &nrow, &rows);
    if (nrow != 6) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk: Hp must have 6 rows"));
    }
    for (int i = 0; i < 6; i++) {
        H[i] = vec(rows[i], m);
    }
}

// between(Hp, S, P, ld, ia, ic, A, B, T, qa3, m): stkf_kernels.between. Hp (6 rows of m,
// a list of 6 float buffers) = A P[a rows, :] + B P[c rows, :]; S (6 x 6) = P_bb, the upper triangle
// mirrored, with (I - B Fb) Qa (T = I - B Fb; qa3 = (q3, q2, q1), Qa per axis [[q3, q2], [q2, q1]]).
static mp_obj_t between(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[3]), ia = sz(args[4]), ic = sz(args[5]), m = sz(args[10]);
    vec_t H[6];
    rows6(args[0], m, H);
    double a[36], b[36], tq[36], q[3];
    vals(args[6], a, 36);
    vals(args[7], b, 36);
    vals(args[8], tq, 36);
    vals(args[9], q, 3);
    size_t top = (ia > ic ? ia : ic) * 6 + 6;
    if (m > ld || top > ld || ic * 6 + 6 > m || ia * 6 + 6 > m) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.between: nodes out of range"));
    }
    vec_t P = vec(args[2], top * ld), S = vec(args[1], 36);
    size_t sa = ia * 6 * ld, sc = ic * 6 * ld;
    for (size_t j = 0; j < m; j++) {
        double p[6], c[6];
        for (int k = 0; k < 6; k++) {
            p[k] = rd(&P, sa + j + k * ld);
            c[k] = rd(&P, sc + j + k * ld);
        }
        for (int i = 0; i < 6; i++) {
            const double *ai = a + 6 * i, *bi = b + 6 * i;
            double v = ai[0] * p[0] + ai[1] * p[1] + ai[2] * p[2] + ai[3] * p[3] + ai[4] * p[4] + ai[5] * p[5]
                + bi[0] * c[0] + bi[1] * c[1] + bi[2] * c[2] + bi[3] * c[3] + bi[4] * c[4] + bi[5] * c[5];
            wr(&H[i], j, v);
        }
    }
    size_t na = ia * 6, nc = ic * 6;
    for (size_t i = 0; i < 6; i++) {
        size_t o = 6 * i;
        double p[6], c[6], w[6];
        for (int k = 0; k < 6; k++) {
            p[k] = rd(&H[i], na + k);
            c[k] = rd(&H[i], nc + k);
        }
        for (size_t j = i; j < 6; j++) {
            const double *aj = a + 6 * j, *bj = b + 6 * j;
            for (int k = 0; k < 6; k++) {
                w[k] = p[k] * aj[k] + c[k] * bj[k];
            }
            size_t g = j < 3 ? j : j - 3;
            double qg = j < 3 ? q[0] : q[1], qh = j < 3 ? q[1] : q[2];
            w[g] = w[g] + tq[o + g] * qg;
            w[g + 3] = w[g + 3] + tq[o + g + 3] * qh;
            double s = w[0] + w[1] + w[2] + w[3] + w[4] + w[5];
            wr(&S, o + j, s);
            wr(&S, j * 6 + i, s);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(between_obj, 11, 11, between);

// update_rows(P, ld, X, Hp, S, R, L, d, r, z, m): LeanStkf._update_rows (Eq. 5.24): S += R (lower triangle),
// S = L L^T, r = z - h, V = L^-1 Hp in place, X += V^T L^-1 r, P -= V^T V (upper triangle, mirrored).
// False (nothing but S, L and r changed) unless S is positive definite.
static mp_obj_t update_rows(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]), m = sz(args[10]);
    if (m > ld) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.update_rows: m > ld"));
    }
    vec_t V[6];
    rows6(args[3], m, V);
    vec_t P = vec(args[0], m * ld), X = vec(args[2], m), S = vec(args[4], 36);
    vec_t L = vec(args[6], 36), d = vec(args[7], 12), r = vec(args[8], 6);
    double z[6], R[36];
    vals(args[9], z, 6);
    vals(args[5], R, 36);
    for (size_t i = 0; i < 6; i++) {
        for (size_t j = i * 6; j < i * 7 + 1; j++) {
            wr(&S, j, rd(&S, j) + R[j]);
        }
    }
    if (!k_cholesky(&L, &S, 6)) {
        return mp_const_false;
    }
    for (size_t j = 0; j < 6; j++) {
        wr(&r, j, z[j] - rd(&d, 6 + j));
    }
    double l[36];
    for (int k = 0; k < 36; k++) {
        l[k] = rd(&L, k);
    }
    double rr[6];
    for (int i = 0; i < 6; i++) {                    // L^-1 (z - h)
        double s = rd(&r, i);
        for (int k = 0; k < i; k++) {
            s = s - l[6 * i + k] * rr[k];
        }
        rr[i] = s / l[7 * i];
    }
    for (size_t j = 0; j < m; j++) {                 // V = L^-1 Hp, column by column, in place; X += V^T r
        double v[6];
        for (int i = 0; i < 6; i++) {
            double s = rd(&V[i], j);
            for (int k = 0; k < i; k++) {
                s = s - l[6 * i + k] * v[k];
            }
            v[i] = s / l[7 * i];
        }
        for (int i = 0; i < 6; i++) {
            wr(&V[i], j, v[i]);
        }
        wr(&X, j, rd(&X, j) + v[0] * rr[0] + v[1] * rr[1] + v[2] * rr[2] + v[3] * rr[3] + v[4] * rr[4] + v[5] * rr[5]);
    }
    for (size_t i = 0; i < m; i++) {
        double v[6];
        for (int k = 0; k < 6; k++) {
            v[k] = rd(&V[k], i);
        }
        size_t a = i * ld, b = a + i;
        for (size_t j = i; j < m; j++) {
            double u = rd(&P, a + j) - (v[0] * rd(&V[0], j) + v[1] * rd(&V[1], j) + v[2] * rd(&V[2], j)
                                        + v[3] * rd(&V[3], j) + v[4] * rd(&V[4], j) + v[5] * rd(&V[5], j));
            wr(&P, a + j, u);
            wr(&P, b, u);
            b += ld;
        }
    }
    return mp_const_true;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(update_rows_obj, 11, 11, update_rows);

// ---- stkf_dmc.py (nodes of 9 states: r, v, w) -------------------------------------------------------------

// v[j] = (Phi p)[j] for j0 <= j < 9 over Phi's nonzero columns only (stkf_dmc.PHI_NZ: an r row r, v and its w; a
// v row all; a w row its w), summed from 0.0 in that order: stkf_dmc._phi_vec
static void phi_vec(const double *f, const double *p, double *v, int j0) {
    for (int j = j0; j < 9; j++) {
        const double *fj = f + 9 * j;
        double t = 0.0;
        if (j < 6) {
            for (int k = 0; k < 6; k++) {
                t = t + fj[k] * p[k];
            }
        }
        if (j >= 3 && j < 6) {
            for (int k = 6; k < 9; k++) {
                t = t + fj[k] * p[k];
            }
        } else {
            int k = j < 3 ? j + 6 : j;
            t = t + fj[k] * p[k];
        }
        v[j] = t;
    }
}

// p = P[s + k ld] for k < 9 (a column of 9 rows from P's entry s)
static void col9(const vec_t *P, size_t ld, size_t s, double *p) {
    for (int k = 0; k < 9; k++) {
        p[k] = rd(P, s + k * ld);
    }
}

// rows_mul_phi(P, ld, src, c_lo, c_hi, F, p, v): p, v (the Python form's work) are not used
static mp_obj_t rows_mul_phi(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]), src = sz(args[2]), c_lo = sz(args[3]), c_hi = sz(args[4]);
    double f[81];
    vals(args[5], f, 81);
    if (c_hi > ld || src + 9 > ld) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.rows_mul_phi: columns out of range"));
    }
    vec_t P = vec(args[0], (src + 9 > c_hi ? src + 9 : c_hi) * ld);
    for (size_t c = c_lo; c < c_hi; c++) {
        double p[9], v[9];
        col9(&P, ld, src * ld + c, p);
        phi_vec(f, p, v, 0);
        for (size_t k = 0; k < 9; k++) {
            wr(&P, k * ld + c, v[k]);
            wr(&P, c * ld + k, v[k]);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(rows_mul_phi_obj, 8, 8, rows_mul_phi);

// sandwich_phi(P, ld, r0, src, F, Q, T, p, v): T (81) in its own precision, as the Python form's; p, v not used
static mp_obj_t sandwich_phi(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]), r0 = sz(args[2]), src = sz(args[3]);
    double f[81], q[81];
    vals(args[4], f, 81);
    vals(args[5], q, 81);
    size_t hi = (src > r0 ? src : r0) + 9;
    if (hi > ld) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.sandwich_phi: rows out of range"));
    }
    vec_t P = vec(args[0], hi * ld), T = vec(args[6], 81);
    double p[9], v[9];
    for (size_t c = 0; c < 9; c++) {                 // T = F P, column by column
        col9(&P, ld, src * ld + src + c, p);
        phi_vec(f, p, v, 0);
        for (size_t k = 0; k < 9; k++) {
            wr(&T, 9 * k + c, v[k]);
        }
    }
    for (size_t i = 0; i < 9; i++) {                 // row i: F T[i, :]^T + Q[i, :], from its diagonal, mirrored
        for (size_t k = 0; k < 9; k++) {
            p[k] = rd(&T, 9 * i + k);
        }
        phi_vec(f, p, v, (int)i);
        for (size_t j = i; j < 9; j++) {
            wr_sym(&P, ld, r0 + i, r0 + j, q[9 * i + j] + v[j]);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(sandwich_phi_obj, 9, 9, sandwich_phi);

// the older nodes' columns c of rows 0..8, and their mirror, times I - K H: joseph_dmc's first part
static void ikh9_rows(vec_t *P, size_t ld, size_t m, const double *kt, const double *h) {
    for (size_t c = 9; c < m; c++) {
        double u[3];
        for (int a = 0; a < 3; a++) {
            u[a] = h[3 * a] * rd(P, c) + h[3 * a + 1] * rd(P, ld + c) + h[3 * a + 2] * rd(P, 2 * ld + c);
        }
        for (size_t i = 0; i < 9; i++) {
            double t = rd(P, i * ld + c) - (kt[i] * u[0] + kt[9 + i] * u[1] + kt[18 + i] * u[2]);
            wr(P, i * ld + c, t);
            wr(P, c * ld + i, t);
        }
    }
}

// joseph_dmc(P, ld, m, Kt, U, H, R, W, u): stkf_dmc._joseph_dmc; u (the Python form's work) is not used
static mp_obj_t joseph_dmc(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[1]), m = sz(args[2]);
    double kt[27], u[27], h[9], r[9];
    vals(args[3], kt, 27);
    vals(args[4], u, 27);
    vals(args[5], h, 9);
    vals(args[6], r, 9);
    if (m > ld || 9 > ld) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.joseph_dmc: columns out of range"));
    }
    vec_t P = vec(args[0], (m > 9 ? m : 9) * ld), W = vec(args[7], 81);
    ikh9_rows(&P, ld, m, kt, h);
    for (size_t i = 0; i < 9; i++) {                 // W = P00 - K U
        for (size_t j = 0; j < 9; j++) {
            wr(&W, 9 * i + j, rd(&P, i * ld + j) - (kt[i] * u[j] + kt[9 + i] * u[9 + j] + kt[18 + i] * u[18 + j]));
        }
    }
    for (size_t i = 0; i < 9; i++) {                 // P00 = W - (W H^T) K^T + (K R) K^T, upper triangle mirrored
        double w0 = rd(&W, 9 * i), w1 = rd(&W, 9 * i + 1), w2 = rd(&W, 9 * i + 2);
        double k0 = kt[i], k1 = kt[9 + i], k2 = kt[18 + i], v[3], kr[3];
        for (int a = 0; a < 3; a++) {
            v[a] = w0 * h[3 * a] + w1 * h[3 * a + 1] + w2 * h[3 * a + 2];
            kr[a] = k0 * r[a] + k1 * r[3 + a] + k2 * r[6 + a];
        }
        for (size_t j = i; j < 9; j++) {
            double g0 = kt[j], g1 = kt[9 + j], g2 = kt[18 + j];
            double t = rd(&W, 9 * i + j) - (v[0] * g0 + v[1] * g1 + v[2] * g2)
                       + (kr[0] * g0 + kr[1] * g1 + kr[2] * g2);
            wr_sym(&P, ld, i, j, t);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(joseph_dmc_obj, 9, 9, joseph_dmc);

// hp_rows(Hp, P, ld, ia, ic, m, AB, pq, A, B): stkf_dmc._hp_rows; AB, pq (the Python form's work) are not used
static mp_obj_t hp_rows(size_t n_args, const mp_obj_t *args) {
    size_t ld = sz(args[2]), ia = sz(args[3]), ic = sz(args[4]), m = sz(args[5]);
    size_t top = (ia > ic ? ia : ic) * 9 + 9;
    if (m > ld || top > ld) {
        mp_raise_ValueError(MP_ERROR_TEXT("adcsk.hp_rows: nodes out of range"));
    }
    vec_t H[6];
    rows6(args[0], m, H);
    double ab[108];                                  // row a: A's row a, then B's
    vals(args[8], ab, 54);
    vals(args[9], ab + 54, 54);
    vec_t P = vec(args[1], top * ld);
    for (size_t j = 0; j < m; j++) {
        double pq[18];
        col9(&P, ld, ia * 9 * ld + j, pq);
        col9(&P, ld, ic * 9 * ld + j, pq + 9);
        for (int a = 0; a < 6; a++) {
            double t = 0.0;
            for (int k = 0; k < 9; k++) {
                t = t + ab[9 * a + k] * pq[k];
            }
            for (int k = 0; k < 9; k++) {
                t = t + ab[54 + 9 * a + k] * pq[9 + k];
            }
            wr(&H[a], j, t);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(hp_rows_obj, 10, 10, hp_rows);

// s_between(S, Hp, ia, ic, A, B, T, Qa): stkf_dmc._s_between
static mp_obj_t s_between(size_t n_args, const mp_obj_t *args) {
    size_t ia = sz(args[2]), ic = sz(args[3]);
    vec_t H[6];
    rows6(args[1], (ia > ic ? ia : ic) * 9 + 9, H);
    double a[81], b[81], t[81], qa[81];
    vals(args[4], a, 81);
    vals(args[5], b, 81);
    vals(args[6], t, 81);
    vals(args[7], qa, 81);
    vec_t S = vec(args[0], 36);
    size_t ca = ia * 9, cc = ic * 9;
    for (size_t i = 0; i < 6; i++) {
        for (size_t j = i; j < 6; j++) {
            double v = 0.0;
            for (size_t k = 0; k < 9; k++) {
                v = v + (rd(&H[i], ca + k) * a[9 * j + k] + rd(&H[i], cc + k) * b[9 * j + k]
                         + t[9 * i + k] * qa[9 * k + j]);
            }
            wr(&S, 6 * i + j, v);
            wr(&S, 6 * j + i, v);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(s_between_obj, 8, 8, s_between);

// ---- apkf_lean.py -----------------------------------------------------------------------------------------

// phi9(Phi, F, dt, T, order): apkf_lean.phi with work.T1 = T
static mp_obj_t phi9(size_t n_args, const mp_obj_t *args) {
    double dt = mp_obj_get_float_to_d(args[2]);
    mp_int_t order = mp_obj_get_int(args[4]);
    vec_t Phi = vec(args[0], 81), T = vec(args[3], 54);
    double F[54], tl[54];
    vals(args[1], F, 54);
    for (int i = 0; i < 54; i++) {
        double t = F[i] * dt;
        wr(&T, i, t);
        wr(&Phi, i, i % 10 == 0 ? 1.0 + t : t);
    }
    for (int i = 54; i < 81; i++) {
        wr(&Phi, i, i % 10 == 0 ? 1.0 : 0.0);
    }
    for (int i = 0; i < 54; i++) {
        tl[i] = rd(&T, i);
    }
    const double *f3 = F + 27, *f4 = F + 36, *f5 = F + 45;
    for (mp_int_t n = 2; n <= order; n++) {
        double c = dt / (double)n;
        for (int o = 0; o < 54; o += 9) {
            const double *t = tl + o;
            wr(&T, o, (t[1] * F[9] + t[2] * F[18] + t[3] * f3[0] + t[4] * f4[0] + t[5] * f5[0]) * c);
            wr(&T, o + 1, (t[0] * F[1] + t[2] * F[19] + t[3] * f3[1] + t[4] * f4[1] + t[5] * f5[1]) * c);
            wr(&T, o + 2, (t[0] * F[2] + t[1] * F[11] + t[3] * f3[2] + t[4] * f4[2] + t[5] * f5[2]) * c);
            wr(&T, o + 3, (t[0] * 0.5 + t[3] * f3[3] + t[4] * f4[3] + t[5] * f5[3]) * c);
            wr(&T, o + 4, (t[1] * 0.5 + t[3] * f3[4] + t[4] * f4[4] + t[5] * f5[4]) * c);
            wr(&T, o + 5, (t[2] * 0.5 + t[3] * f3[5] + t[4] * f4[5] + t[5] * f5[5]) * c);
            wr(&T, o + 6, (t[3] * f3[6] + t[4] * f4[6] + t[5] * f5[6]) * c);
            wr(&T, o + 7, (t[3] * f3[7] + t[4] * f4[7] + t[5] * f5[7]) * c);
            wr(&T, o + 8, (t[3] * f3[8] + t[4] * f4[8] + t[5] * f5[8]) * c);
        }
        for (int i = 0; i < 54; i++) {
            tl[i] = rd(&T, i);
        }
        for (int i = 0; i < 54; i++) {
            wr(&Phi, i, rd(&Phi, i) + tl[i]);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_VAR_BETWEEN(phi9_obj, 5, 5, phi9);

// covariance_predict(P, Phi, T): apkf_lean.covariance_predict
static mp_obj_t covariance_predict(mp_obj_t P_in, mp_obj_t Phi_in, mp_obj_t T_in) {
    vec_t P = vec(P_in, 81), T = vec(T_in, 54);
    double Pr[81], Ph[54], Tr[54];
    vals(P_in, Pr, 81);
    vals(Phi_in, Ph, 54);
    for (int i = 0; i < 6; i++) {
        const double *a = Ph + 9 * i;
        for (int j = 0; j < 9; j++) {
            const double *b = Pr + 9 * j;
            wr(&T, i * 9 + j, a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]
               + a[6] * b[6] + a[7] * b[7] + a[8] * b[8]);
        }
    }
    for (int i = 0; i < 54; i++) {
        Tr[i] = rd(&T, i);
    }
    for (int i = 0; i < 6; i++) {
        const double *a = Tr + 9 * i;
        for (int j = i; j < 6; j++) {
            const double *b = Ph + 9 * j;
            double v = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]
                + a[6] * b[6] + a[7] * b[7] + a[8] * b[8];
            wr(&P, i * 9 + j, v);
            wr(&P, j * 9 + i, v);
        }
        for (int j = 6; j < 9; j++) {
            wr(&P, i * 9 + j, a[j]);
            wr(&P, j * 9 + i, a[j]);
        }
    }
    return mp_const_none;
}
static MP_DEFINE_CONST_FUN_OBJ_3(covariance_predict_obj, covariance_predict);

// every function the module exports: (its name, its function object); the names spelled out, as the native
// module build's qstr scan reads them from this text
#define ADCSK_FUNCS(X) \
    X(MP_QSTR_matmul, matmul_obj) \
    X(MP_QSTR_matmul_bt, matmul_bt_obj) \
    X(MP_QSTR_symmetrize, symmetrize_obj) \
    X(MP_QSTR_cholesky, cholesky_obj) \
    X(MP_QSTR_chol_solve_rows, chol_solve_rows_obj) \
    X(MP_QSTR_joseph_select, joseph_select_obj) \
    X(MP_QSTR_rows_mul_mirror, rows_mul_mirror_obj) \
    X(MP_QSTR_sandwich, sandwich_obj) \
    X(MP_QSTR_ikh_rows, ikh_rows_obj) \
    X(MP_QSTR_ikh_sandwich, ikh_sandwich_obj) \
    X(MP_QSTR_between, between_obj) \
    X(MP_QSTR_update_rows, update_rows_obj) \
    X(MP_QSTR_rows_mul_phi, rows_mul_phi_obj) \
    X(MP_QSTR_sandwich_phi, sandwich_phi_obj) \
    X(MP_QSTR_joseph_dmc, joseph_dmc_obj) \
    X(MP_QSTR_hp_rows, hp_rows_obj) \
    X(MP_QSTR_s_between, s_between_obj) \
    X(MP_QSTR_phi9, phi9_obj) \
    X(MP_QSTR_covariance_predict, covariance_predict_obj)

#ifdef ADCSK_BUILTIN

#define ADCSK_ENTRY(q, o) { MP_ROM_QSTR(q), MP_ROM_PTR(&o) },
static const mp_rom_map_elem_t adcsk_globals_table[] = {
    { MP_ROM_QSTR(MP_QSTR___name__), MP_ROM_QSTR(MP_QSTR_adcsk) },
    ADCSK_FUNCS(ADCSK_ENTRY)
};
static MP_DEFINE_CONST_DICT(adcsk_globals, adcsk_globals_table);

const mp_obj_module_t adcsk_module = {
    .base = { &mp_type_module },
    .globals = (mp_obj_dict_t *)&adcsk_globals,
};
MP_REGISTER_MODULE(MP_QSTR_adcsk, adcsk_module);

#elif !defined(ADCSK_CPYTHON)

#define ADCSK_STORE(q, o) mp_store_global(q, MP_OBJ_FROM_PTR(&o));
mp_obj_t mpy_init(mp_obj_fun_bc_t *self, size_t n_args, size_t n_kw, mp_obj_t *args) {
    MP_DYNRUNTIME_INIT_ENTRY

    ADCSK_FUNCS(ADCSK_STORE)

    MP_DYNRUNTIME_INIT_EXIT
}

#endif
