/* Parameter and time expressions of a scene as bytecode (compiled by compiler/scene_file.py from the parsed
 * expression trees of expr.py; nothing is ever eval-ed).  A program is a sequence of (op, arg) pairs for a
 * stack machine; the code is validated once at load (stack depth, indices), so running it needs no checks.
 * Stage 0 programs run when parameters are bound and write the model numbers (D), stage 1 programs run at
 * every evaluation time and write the time-dependent numbers (drive values and derivatives, force values).
 */
#include <math.h>
#include <stdio.h>

#include "mbs_model.h"

static double call1(int fn, double a)
{
    switch (fn) {
    case FN_SIN: return sin(a);
    case FN_COS: return cos(a);
    case FN_TAN: return tan(a);
    case FN_ASIN: return asin(a);
    case FN_ACOS: return acos(a);
    case FN_ATAN: return atan(a);
    case FN_SINH: return sinh(a);
    case FN_COSH: return cosh(a);
    case FN_TANH: return tanh(a);
    case FN_EXP: return exp(a);
    case FN_LOG: return log(a);
    case FN_SQRT: return sqrt(a);
    default: return fabs(a);
    }
}

static double call2(int fn, double a, double b)
{
    switch (fn) {
    case FN_ATAN2: return atan2(a, b);
    case FN_MIN: return a < b ? a : b;
    default: return a > b ? a : b;
    }
}

static double run(const int32_t *code, int len, const double *params, const double *consts, double t)
{
    double st[MBS_MAXSTACK];
    int sp = 0;
    for (int pc = 0; pc < len; pc += 2) {
        int op = code[pc], arg = code[pc + 1];
        switch (op) {
        case OP_CONST: st[sp++] = consts[arg]; break;
        case OP_PARAM: st[sp++] = params[arg]; break;
        case OP_TIME: st[sp++] = t; break;
        case OP_NEG: st[sp - 1] = -st[sp - 1]; break;
        case OP_ADD: sp--; st[sp - 1] += st[sp]; break;
        case OP_SUB: sp--; st[sp - 1] -= st[sp]; break;
        case OP_MUL: sp--; st[sp - 1] *= st[sp]; break;
        case OP_DIV: sp--; st[sp - 1] /= st[sp]; break;
        case OP_POW: sp--; st[sp - 1] = pow(st[sp - 1], st[sp]); break;
        case OP_CALL1: st[sp - 1] = call1(arg, st[sp - 1]); break;
        case OP_CALL2: sp--; st[sp - 1] = call2(arg, st[sp - 1], st[sp]); break;
        default: {  /* OP_SEL_MIN / OP_SEL_MAX: a b x y → derivative of the active branch of min/max(a, b) */
            sp -= 3;
            double a = st[sp - 1], b = st[sp], x = st[sp + 1], y = st[sp + 2];
            double d = (op == OP_SEL_MIN ? 1.0 : -1.0) * (a - b);
            st[sp - 1] = d < 0 ? x : d > 0 ? y : 0.5 * (x + y);
        }
        }
    }
    return st[0];
}

void mbs_run_programs(const MbsModel *m, int stage, double *D, double *td, double t)
{
    const double *params = D + m->hdr[H_D_PARAM], *consts = D + m->hdr[H_D_CONST];
    for (int p = 0; p < m->hdr[H_NPROG]; p++) {
        const int32_t *row = m->prog + 4 * p;
        if (row[0] != stage) continue;
        double v = run(m->code + row[2], row[3], params, consts, t);
        if (stage == 0) D[row[1]] = v;
        else td[row[1]] = v;
    }
}

/* Every program: ops and arguments in range, the stack never under- or overflows and ends with one value,
 * targets inside D (stage 0, outside the parameter block) or td (stage 1). */
int mbs_validate_code(const MbsModel *m, char *err, size_t errlen)
{
    static const signed char pops[OP_N] = {0, 0, 0, 1, 2, 2, 2, 2, 2, 1, 2, 4, 4};
    static const signed char pushes[OP_N] = {1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1};
    const int ncode = m->hdr[H_NCODE], nconst = m->hdr[H_D_BODY] - m->hdr[H_D_CONST];
    const int ntd = 3 * (m->hdr[H_NDRV] + m->hdr[H_NVEC]);
    for (int p = 0; p < m->hdr[H_NPROG]; p++) {
        const int32_t *row = m->prog + 4 * p;
        int stage = row[0], target = row[1], off = row[2], len = row[3], sp = 0;
        if ((stage != 0 && stage != 1) || off < 0 || len <= 0 || (len & 1) || off > ncode - len ||
            (stage == 0 && (target < m->hdr[H_D_BODY] || target >= m->hdr[H_ND])) ||
            (stage == 1 && (target < 0 || target >= ntd))) {
            snprintf(err, errlen, "program %d: bad stage, target or code range", p);
            return 1;
        }
        for (int pc = off; pc < off + len; pc += 2) {
            int op = m->code[pc], arg = m->code[pc + 1];
            if (op < 0 || op >= OP_N || sp < pops[op] ||
                (op == OP_CONST && (arg < 0 || arg >= nconst)) ||
                (op == OP_PARAM && (arg < 0 || arg >= m->hdr[H_NPARAM])) ||
                (op == OP_CALL1 && (arg < 0 || arg >= FN_N1)) || (op == OP_CALL2 && (arg < 0 || arg >= FN_N2))) {
                snprintf(err, errlen, "program %d: invalid instruction at %d", p, pc - off);
                return 1;
            }
            sp += pushes[op] - pops[op];
            if (sp > MBS_MAXSTACK) {
                snprintf(err, errlen, "program %d: expression too deep for the engine's stack (%d)", p, MBS_MAXSTACK);
                return 1;
            }
        }
        if (sp != 1) {
            snprintf(err, errlen, "program %d: leaves %d values on the stack", p, sp);
            return 1;
        }
    }
    return 0;
}
