/* The scene's domains and rules, applied to the values a host sets, and gimbal lock of Cardan joints. */
#include <math.h>
#include <stdio.h>

#include "mbs_model.h"
#include "rules.h"

/* ------------------------------------------------------------------------------------------ domains
 * scene/domains.py declares them: Domain.contains and check() there, in_domain and rule_problem here, the
 * same rules with the same texts (tests/test_domains.py holds the two equal). */
int mbs_in_domain(const double *d, double v)
{
    const int flags = (int)d[2];
    if (!isfinite(v)) return 0;
    if ((flags & VD_ZERO) && v == 0.0) return 1;
    return ((flags & VD_LO_OPEN) ? v > d[0] : v >= d[0]) && ((flags & VD_HI_OPEN) ? v < d[1] : v <= d[1]);
}

void mbs_domain_text(const double *d, char *buf, size_t len)
{
    const int flags = (int)d[2];
    if (d[0] == -INFINITY && d[1] == INFINITY) { snprintf(buf, len, "a finite number"); return; }
    snprintf(buf, len, "%s%c%g, %g%c", flags & VD_ZERO ? "0 or " : "", flags & VD_LO_OPEN ? '(' : '[', d[0], d[1],
             flags & VD_HI_OPEN ? ')' : ']');
}

/* Eigenvalues of the symmetric part of a 3 × 3 matrix, ascending (cyclic Jacobi: accurate near repeated ones). */
static void eigenvalues3(const double *A, double lam[3])
{
    double a[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) a[3 * r + c] = 0.5 * (A[3 * r + c] + A[3 * c + r]);
    for (int sweep = 0; sweep < 50 && (a[1] != 0 || a[2] != 0 || a[5] != 0); sweep++)
        for (int p = 0; p < 2; p++)
            for (int q = p + 1; q < 3; q++) {
                const double apq = a[3 * p + q];
                if (apq == 0) continue;
                const double th = (a[3 * q + q] - a[3 * p + p]) / (2 * apq);
                const double t = fabs(th) > 1e150 ? 0.5 / th : (th >= 0 ? 1.0 : -1.0) / (fabs(th) + sqrt(th * th + 1));
                const double c = 1 / sqrt(t * t + 1), sn = t * c;
                for (int k = 0; k < 3; k++) {
                    const double kp = a[3 * k + p], kq = a[3 * k + q];
                    a[3 * k + p] = c * kp - sn * kq;
                    a[3 * k + q] = sn * kp + c * kq;
                }
                for (int k = 0; k < 3; k++) {
                    const double pk = a[3 * p + k], qk = a[3 * q + k];
                    a[3 * p + k] = c * pk - sn * qk;
                    a[3 * q + k] = sn * pk + c * qk;
                }
                a[3 * p + q] = a[3 * q + p] = 0.0;
            }
    lam[0] = a[0]; lam[1] = a[4]; lam[2] = a[8];
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2 - i; j++)
            if (lam[j] > lam[j + 1]) { double x = lam[j]; lam[j] = lam[j + 1]; lam[j + 1] = x; }
}

#define RULE_SIZE(code, size) size,
const int mbs_rule_size[R_N] = {MBS_RULES(RULE_SIZE)};

/* NULL if the rule holds for v (mbs_rule_size[rule] numbers), else what is wrong (written into buf). */
const char *mbs_rule_problem(const MbsModel *m, int rule, const double *v, char *buf, size_t len)
{
    const double *lim = m->limits;
    for (int k = 0; k < mbs_rule_size[rule]; k++)
        if (!isfinite(v[k])) return snprintf(buf, len, "is not finite (%g)", v[k]), buf;
    if (rule == R_NONNEG)
        return v[0] >= 0 ? NULL : (snprintf(buf, len, "must not be negative, got %g", v[0]), buf);
    if (rule == R_MAGNITUDE)
        return v[0] == 0 || (fabs(v[0]) >= lim[LIM_MAGNITUDE_LO] && fabs(v[0]) <= lim[LIM_MAGNITUDE_HI]) ? NULL :
               (snprintf(buf, len, "%g is outside the magnitudes a model can compute with (%g to %g, or 0)", v[0],
                         lim[LIM_MAGNITUDE_LO], lim[LIM_MAGNITUDE_HI]), buf);
    if (rule == R_AXIS) {
        const double length = hypot(hypot(v[0], v[1]), v[2]);
        if (length == 0) return snprintf(buf, len, "must not be the zero vector"), buf;
        return length >= lim[LIM_AXIS_LO] && length <= lim[LIM_AXIS_HI] ? NULL :
               (snprintf(buf, len, "a direction of length %.3g (allowed: %g to %g)", length, lim[LIM_AXIS_LO],
                         lim[LIM_AXIS_HI]), buf);
    }
    if (rule == R_PERPENDICULAR || rule == R_NOT_PARALLEL) {  /* two axes, each checked by its R_AXIS row first */
        const double c = fabs(v[0] * v[3] + v[1] * v[4] + v[2] * v[5]) / hypot(hypot(v[0], v[1]), v[2]) /
                         hypot(hypot(v[3], v[4]), v[5]);
        if (rule == R_PERPENDICULAR)
            return c <= 1e-9 ? NULL : (snprintf(buf, len, "the two in-plane axes must be perpendicular"), buf);
        return c <= 1 - 1e-9 ? NULL : (snprintf(buf, len, "the two axes of a universal joint must not be parallel"), buf);
    }
    if (rule == R_ROTATION) {  /* numpy.allclose(RᵀR, I, atol=1e-6) and det R > 0 */
        int ok = v[0] * (v[4] * v[8] - v[5] * v[7]) - v[1] * (v[3] * v[8] - v[5] * v[6]) + v[2] * (v[3] * v[7] - v[4] * v[6]) > 0;
        for (int r = 0; ok && r < 3; r++)
            for (int c = 0; ok && c < 3; c++) {
                const double dot = v[r] * v[c] + v[3 + r] * v[3 + c] + v[6 + r] * v[6 + c], want = r == c;
                ok = fabs(dot - want) <= 1e-6 + 1e-5 * want;
            }
        return ok ? NULL : (snprintf(buf, len, "is not a proper rotation (orthonormal columns, determinant +1)"), buf);
    }
    if (rule == R_INERTIA) {
        double lam[3];
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)  /* numpy.allclose(I, Iᵀ, rtol=1e-9, atol=1e-12) */
                if (!(fabs(v[3 * r + c] - v[3 * c + r]) <= 1e-12 + 1e-9 * fabs(v[3 * c + r])))
                    return snprintf(buf, len, "the inertia tensor must be symmetric"), buf;
        eigenvalues3(v, lam);
        const double tol = 1e-9 * fmax(1.0, fmax(fabs(lam[0]), fabs(lam[2])));
        if (lam[0] < -tol)
            return snprintf(buf, len, "the inertia tensor is not positive semi-definite (principal moments %.4g, %.4g, %.4g)",
                            lam[0], lam[1], lam[2]), buf;
        if (lam[0] + lam[1] < lam[2] - tol)
            return snprintf(buf, len, "principal moments %.4g, %.4g, %.4g break the triangle inequality (I1 + I2 >= I3)",
                            lam[0], lam[1], lam[2]), buf;
    }
    return NULL;
}

/* Gimbal lock of Cardan joints: |cos b| < 1e-3 at x, or b crossed ±90° since x_before (evaluator.py:
 * singularity_message). Writes the message into buf; 1 if locked. */
int mbs_gimbal(const MbsModel *m, const double *x, const double *x_before, char *buf, size_t len)
{
    if (!m->hdr[H_NCARDAN]) return 0;
    for (int i = 0; i < NB(m); i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        const int k = mbs_joints[bi->jtype].gimbal;
        if (k < 0 || bi->pos[k] < 0) continue;
        int idx = bi->pos[k];
        double c = cos(x[idx]);
        if (fabs(c) < 1e-3 || (x_before && cos(x_before[idx]) * c < 0)) {
            snprintf(buf, len, "gimbal lock: Cardan angle %s = %.6g rad reached ±90°, where the x-y-z angles of body "
                     "'%s' are singular; use parameterization: quaternion", m->coord_name[idx], x[idx], m->body_name[i]);
            return 1;
        }
    }
    return 0;
}

