/* Loading the compiled scene: every count, offset and index is checked here, once, so that a corrupt or
 * foreign file ends in a message instead of a crash, and the per-step code can trust the tables. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_files.h"
#include "mbs_integrator.h"
#include "mbs_model.h"
#include "rules.h"

#define FAIL(...) do { snprintf(err, errlen, __VA_ARGS__); goto fail; } while (0)

typedef struct { int32_t id, kind; int64_t offset, count; } Section;  /* a section row (MBS_SECTION_ROW) */
MBS_VIEW_CHECK(section_id, offsetof(Section, id) == SR_ID);
MBS_VIEW_CHECK(section_kind, offsetof(Section, kind) == SR_KIND);
MBS_VIEW_CHECK(section_offset, offsetof(Section, offset) == SR_OFFSET);
MBS_VIEW_CHECK(section_count, offsetof(Section, count) == SR_COUNT);
MBS_VIEW_CHECK(section_size, sizeof(Section) == SR_SIZE);

static const void *section(const unsigned char *b, size_t len, const Section *tab, int nsec, int id, int kind,
                           int64_t want, int *count)
{
    for (int s = 0; s < nsec; s++) {
        if (tab[s].id != id) continue;
        size_t size = kind == 1 ? 8 : kind == 2 ? 1 : 4;
        if (tab[s].kind != kind || tab[s].offset < 0 || tab[s].count < 0 || tab[s].count > (int64_t)(len / size) ||
            tab[s].count > INT32_MAX || (size_t)tab[s].offset > len - (size_t)tab[s].count * size ||
            (tab[s].offset % size) || (want >= 0 && tab[s].count != want))
            return NULL;
        if (count) *count = (int)tab[s].count;
        return b + tab[s].offset;
    }
    return want == 0 ? b : NULL;  /* an absent section is an empty one */
}

static int in(int64_t v, int64_t lo, int64_t hi) { return v >= lo && v < hi; }

/* The checks below return 1 with a message in err. Sums and products of file values are taken in 64 bits. */
#define BAD(...) do { snprintf(err, errlen, __VA_ARGS__); return 1; } while (0)

#define JOINT_ROW(code, kind, param, npos, nvel, naxes, rot, gimbal) {npos, nvel, naxes, rot, gimbal},
const MbsJointType mbs_joints[J_N] = {MBS_JOINTS(JOINT_ROW)};
#define VAR_KIND_ROW(code, name, set, state, role) {set, state, role},
const MbsVarKind mbs_var_kinds[MBS_V_N] = {MBS_VAR_KINDS(VAR_KIND_ROW)};

/* Header counts: non-negative and each bounded by bytes of the file. The body, force, output, coordinate and
 * parameter counts size the number layout of D, whose length the D section must match (so D's bytes bound
 * them); positions follow from velocities and quaternions; the other counts size their own sections (checked as
 * they are found); vector slots belong to force elements and drives to driven coordinates (check_bodies). The
 * per-instance workspace has the same limit as compiler/scene_file.py's. */
static int check_header(const int32_t *H, char *err, size_t errlen)
{
    for (int k = 0; k < H_SIZE; k++)
        if (H[k] < 0) BAD("corrupt header (field %d is %d, a count or offset >= 0)", k, (int)H[k]);
    const int64_t nb = H[H_NB], np = H[H_NPOS], nv = H[H_NVEL], nf = H[H_NFORCE];
    if (!(H[H_D_PARAM] == 0 && H[H_D_CONST] == H[H_NPARAM] && H[H_D_CONST] <= H[H_D_BODY] &&
          H[H_D_FORCE] == H[H_D_BODY] + nb * DB && H[H_D_G] == H[H_D_FORCE] + nf * DF && H[H_D_X0] == H[H_D_G] + 3 &&
          H[H_D_NOMINAL] == (int64_t)H[H_D_X0] + np + nv && H[H_D_OUT] == (int64_t)H[H_D_NOMINAL] + np + nv && H[H_D_INTEG] == H[H_D_OUT] + 3 * (int64_t)H[H_NOUT] &&
          H[H_ND] == (int64_t)H[H_D_INTEG] + DI))
        BAD("corrupt number layout (the header's counts and offsets into D disagree)");
    if (!in(H[H_METHOD], 0, MBS_NMETHODS))
        BAD("corrupt header (integrator %d, valid 0..%d)", (int)H[H_METHOD], MBS_NMETHODS - 1);
    /* a position coordinate per velocity coordinate, and a fourth one per quaternion; the rest are plain */
    if (np != nv + H[H_NQUAT] || H[H_NPLAIN] != nv - 3 * (int64_t)H[H_NQUAT])
        BAD("corrupt header (%lld positions, %lld velocities, %d quaternions, %d plain coordinates: positions = "
            "velocities + quaternions, plain = velocities - 3 quaternions)", (long long)np, (long long)nv,
            (int)H[H_NQUAT], (int)H[H_NPLAIN]);
    if (H[H_NVEC] > nf || H[H_NINPUT] > H[H_NVEC])
        BAD("corrupt header (%d force inputs, %d vector slots, %lld force elements: inputs <= slots <= elements)",
            (int)H[H_NINPUT], (int)H[H_NVEC], (long long)nf);
    if (H[H_FEATURES] & ~(F_EXPR | F_ELASTIC)) BAD("corrupt header (unknown feature bits %#x)", (unsigned)H[H_FEATURES]);
    if (H[H_DENSE] > 1) BAD("corrupt header (evaluation path %d, valid 0 recursive, 1 dense)", (int)H[H_DENSE]);
#ifndef MBS_WITH_ELASTIC
    if (H[H_FEATURES] & F_ELASTIC)
        BAD("the scene has elastic bodies but this engine was built without them (rebuild the FMU)");
#endif
    const double work = 8.0 * mbs_work_doubles(H);
    if (work > MBS_MAX_WORKSPACE)
        BAD("scene too large for the engine: %lld bodies with %lld velocity coordinates need %.3g GiB of workspace "
            "(limit %.0f GiB)", (long long)nb, (long long)nv, work / (1 << 30), (double)MBS_MAX_WORKSPACE / (1 << 30));
    return 0;
}

/* coordinate idx of body i in [0, n), or -1 (driven) with drive slot drv in [0, ndrv) */
static int check_coordinate(int i, int idx, int drv, int n, int ndrv, const char *what, char *err, size_t errlen)
{
    if (!in(idx, -1, n)) BAD("corrupt body table (body %d: %s %d, valid -1..%d)", i, what, idx, n - 1);
    if (idx < 0 && !in(drv, 0, ndrv)) BAD("corrupt body table (body %d: drive %d, valid 0..%d)", i, drv, ndrv - 1);
    return 0;
}

/* The recursive path (dynamics.c) writes ÿ of each velocity coordinate from the one joint that moves it: in a
 * rigid scene every velocity coordinate belongs to exactly one joint (the dense path would see an unowned one as a
 * singular M; this one would leave its ÿ unwritten). nv is bounded by D's bytes (check_header). */
static int check_owners(const MbsModel *m, char *err, size_t errlen)
{
    const int nv = m->hdr[H_NVEL];
    unsigned char *owned = calloc((size_t)nv + 1, 1);
    int bad = -1;
    if (!owned) BAD("out of memory");
    for (int i = 0; i < NB(m) && bad < 0; i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        for (int k = 0; k < bi->nvel && bad < 0; k++)
            if (bi->vel[k] >= 0 && owned[bi->vel[k]]++) bad = bi->vel[k];
    }
    const int ne = (m->hdr[H_FEATURES] & F_ELASTIC) ? m->elastic_i[EH_NE] : 0;  /* (rows validated) */
    for (int el = 0; el < ne && bad < 0; el++) {
        const int32_t *r = m->elastic_i + EH + EI * el;
        for (int k = 0; k < r[EI_N] && bad < 0; k++)
            if (owned[r[EI_QD] + k]++) bad = r[EI_QD] + k;
    }
    for (int c = 0; c < nv && bad < 0; c++)
        if (!owned[c]) bad = c;
    free(owned);
    if (bad >= 0) BAD("corrupt body table (velocity coordinate %d is not moved by exactly one joint or elastic body)", bad);
    return 0;
}

/* Each body: parent before it, joint type with its own coordinate counts, coordinates or drive slots in range, its
 * carrier itself or (welded) its parent's; no more drives than driven coordinates, the header's Cardan and carrier
 * counts the body table's. Elastic data and nodes are
 * named only by a scene with the elastic feature (whose tables mbs_elastic_validate checks against them). */
static int check_bodies(const MbsModel *m, char *err, size_t errlen)
{
    const int32_t *H = m->hdr;
    const int nb = H[H_NB], np = H[H_NPOS], nv = H[H_NVEL], ndrv = H[H_NDRV], elastic = H[H_FEATURES] & F_ELASTIC;
    int64_t driven = 0, cardan = 0, carriers = 0;
    for (int i = 0; i < nb; i++) {
        const MbsBodyI *bi = mbs_body_i(m, i);
        const int t = bi->jtype;
        if (!in(bi->parent, -1, i))
            BAD("corrupt body table (body %d: parent %d, valid -1..%d)", i, (int)bi->parent, i - 1);
        if (!in(t, 0, J_N) || bi->npos != mbs_joints[t].npos || bi->nvel != mbs_joints[t].nvel)
            BAD("corrupt body table (body %d: joint type %d with %d/%d coordinates)", i, t, (int)bi->npos,
                (int)bi->nvel);
        if (!in(bi->rot, 0, 3) || !in(bi->irot, 0, 3)) BAD("corrupt body table (body %d: rotation code)", i);
        for (int k = 0; k < bi->npos; k++) {
            if (check_coordinate(i, bi->pos[k], bi->drv[k], np, ndrv, "coordinate", err, errlen)) return 1;
            driven += bi->pos[k] < 0;
        }
        for (int k = 0; k < bi->nvel; k++)
            if (check_coordinate(i, bi->vel[k], bi->drv[k], nv, ndrv, "velocity", err, errlen)) return 1;
        cardan += mbs_joints[t].gimbal >= 0;
        if (bi->elastic < -1 || bi->node < -1 || (!elastic && (bi->elastic >= 0 || bi->node >= 0)))
            BAD("corrupt body table (body %d: elastic data %d, node %d in a scene %s elastic bodies)", i,
                (int)bi->elastic, (int)bi->node, elastic ? "with" : "without");
        const MbsBodyI *bp = bi->parent >= 0 ? mbs_body_i(m, bi->parent) : NULL;
        if (bi->carrier != i && !(t == J_FIXED && bi->elastic < 0 && bi->node < 0 && (!bp || bp->elastic < 0) &&
                                  bi->carrier == (bp ? bp->carrier : -1)))
            BAD("corrupt body table (body %d: carrier %d, valid: itself, or for a rigid body on a fixed joint its "
                "rigid parent's carrier)", i, (int)bi->carrier);
        carriers += bi->carrier == i;
    }
    if (ndrv > driven) BAD("corrupt header (%d drives for %lld driven coordinates)", ndrv, (long long)driven);
    if (H[H_NCARDAN] != cardan)
        BAD("corrupt header (%d Cardan joints, the body table has %lld)", (int)H[H_NCARDAN], (long long)cardan);
    if (H[H_NCARRIER] != carriers)
        BAD("corrupt header (%d carriers, the body table has %lld)", (int)H[H_NCARRIER], (long long)carriers);
    return 0;
}

/* Force elements: type, the coordinates or bodies they act on, their value slot; nodes only with elastic bodies. */
static int check_forces(const MbsModel *m, char *err, size_t errlen)
{
    const int32_t *H = m->hdr;
    const int nb = H[H_NB], elastic = H[H_FEATURES] & F_ELASTIC;
    const int64_t ntd = 3 * ((int64_t)H[H_NDRV] + H[H_NVEC]);
    for (int e = 0; e < H[H_NFORCE]; e++) {
        const MbsForceI *fi = mbs_force_i(m, e);
        int ok = in(fi->type, 0, FE_N) && (fi->src == -1 || in(fi->src, 0, ntd - 2)) && fi->node_a >= -1 &&
                 fi->node_b >= -1 && (elastic || (fi->node_a < 0 && fi->node_b < 0));
        if (fi->type == FE_JOINT_SPRING) ok = ok && in(fi->a, 0, H[H_NPOS]) && in(fi->b, 0, H[H_NVEL]);
        else if (fi->type == FE_SPRING) ok = ok && in(fi->a, -1, nb) && in(fi->b, -1, nb);
        else ok = ok && in(fi->a, 0, nb);
        if (!ok) BAD("corrupt force table (element %d: type 0..3, its coordinates or bodies in range, value slot -1 or "
                     "one of %lld, nodes only in a scene with elastic bodies)", e, (long long)ntd / 3);
    }
    return 0;
}

/* Quaternion and plain coordinate lists, variables, outputs: every index inside what it indexes. */
static int check_tables(const MbsModel *m, char *err, size_t errlen)
{
    const int32_t *H = m->hdr;
    const int np = H[H_NPOS], nv = H[H_NVEL], elastic = H[H_FEATURES] & F_ELASTIC;
    for (int j = 0; j < H[H_NQUAT]; j++)
        for (int k = 0; k < 7; k++)
            if (!in(m->quat[7 * j + k], 0, k < 4 ? np : nv)) BAD("corrupt quaternion table (quaternion %d)", j);
    for (int k = 0; k < H[H_NPLAIN]; k++)
        if (!in(m->plain[k], 0, np) || !in(m->plain[H[H_NPLAIN] + k], 0, nv)) BAD("corrupt coordinate table (entry %d)", k);
    const int64_t count[MBS_V_N] = {  /* the indices of each kind of variable (an integrator setting: one) */
        [MBS_V_PARAM] = H[H_NPARAM], [MBS_V_METHOD] = 1, [MBS_V_RTOL] = 1, [MBS_V_ATOL] = 1, [MBS_V_MAX_STEP] = 1,
        [MBS_V_STEP] = 1, [MBS_V_QIN] = nv, [MBS_V_FIN] = 3 * (int64_t)H[H_NINPUT], [MBS_V_Y] = np, [MBS_V_YD] = nv,
        [MBS_V_OUT] = 6 * (int64_t)H[H_NOUT], [MBS_V_DER] = (int64_t)np + nv, [MBS_V_VM] = m->nstress};
    for (int k = 0; k < H[H_NVARS]; k++) {
        const int kind = m->vars[2 * k], idx = m->vars[2 * k + 1];
        if (!in(kind, 0, MBS_V_N) || !in(idx, 0, count[kind]))
            BAD("corrupt variable table (row %d: kind %d, index %d)", k, kind, idx);
    }
    for (int k = 0; k < H[H_NOUT]; k++) {
        const int32_t *o = m->out + 3 * k;
        if (!in(o[0], 0, H[H_NB]) || o[1] < -1 || (!elastic && o[1] >= 0) || !in(o[2], 0, 4))
            BAD("corrupt output table (output %d: body %d of %d, node %d%s, quantities %d of 0..3)", k, (int)o[0],
                (int)H[H_NB], (int)o[1], elastic ? "" : " in a scene without elastic bodies", (int)o[2]);
    }
    return 0;
}

/* FMI 3.0's variables (S_ARRAYS: (first row, rows) of each array, in row order; absent: none): first3[k] is
 * the first row of FMI 3.0 variable k, first3[nvars3] = nvars. Arrays hold Float64 rows only. */
/* The domain rules' table (S_RULES, S_LIMITS, S_VDOM) in range at load: what rules.c's checks of the values then read. */

static int check_rules_table(const MbsModel *m, char *err, size_t errlen)
{
    const int nd = m->hdr[H_ND], ntd = 3 * (m->hdr[H_NDRV] + m->hdr[H_NVEC]);
    const double *lim = m->limits;
    if (!(isfinite(lim[LIM_START]) && isfinite(lim[LIM_STOP]) && lim[LIM_START] <= lim[LIM_STOP] &&
          lim[LIM_SAMPLES] >= 1 && lim[LIM_SAMPLES] <= 100000 && lim[LIM_SAMPLES] == (int)lim[LIM_SAMPLES] &&
          lim[LIM_MAGNITUDE_LO] > 0 && lim[LIM_MAGNITUDE_LO] <= lim[LIM_MAGNITUDE_HI] && isfinite(lim[LIM_MAGNITUDE_HI]) &&
          lim[LIM_AXIS_LO] > 0 && lim[LIM_AXIS_LO] <= lim[LIM_AXIS_HI] && isfinite(lim[LIM_AXIS_HI])))
        return snprintf(err, errlen, "corrupt limits"), 1;
    for (int k = 0; k <= MBS_V_STEP; k++) {
        const double *d = m->vdom + 3 * k;
        if (!(d[2] >= 0 && d[2] < 8 && d[2] == (int)d[2]) || !(d[0] <= d[1]))
            return snprintf(err, errlen, "corrupt variable domain (row %d)", k), 1;
    }
    for (int r = 0; r < m->nrules; r++) {
        const int32_t *row = m->rules + 3 * r;
        const int size = row[0] >= 0 && row[0] < R_N ? mbs_rule_size[row[0]] : -1;
        const int ok = row[0] == R_TIMED ? row[1] >= 0 && row[1] < ntd : size == 0 ? row[1] >= 0 && row[1] < NB(m) :
                       size > 0 && row[1] >= 0 && row[1] <= nd - size;
        if (!ok || row[2] < 0 || row[2] >= m->n_rule_names || !memchr(m->rule_names + row[2], 0, (size_t)(m->n_rule_names - row[2])))
            return snprintf(err, errlen, "corrupt rule table (row %d)", r), 1;
    }
    return 0;
}

static int fmi3_variables(MbsModel *m, const int32_t *arrays, int n, char *err, size_t errlen)
{
    const int nvars = m->hdr[H_NVARS];
    if (!arrays) n = 0;
    if (n % 2) BAD("corrupt array table");
    if (!(m->first3 = malloc(((size_t)nvars + 1) * sizeof *m->first3))) BAD("out of memory");
    int row = 0, k = 0;
    for (int a = 0; a <= n / 2; a++) {
        const int first = a < n / 2 ? arrays[2 * a] : nvars, rows = a < n / 2 ? arrays[2 * a + 1] : 0;
        if (!in(first, row, nvars + 1) || !in(rows, a < n / 2, nvars - first + 1))
            BAD("corrupt array table (array %d: %d rows from row %d, after row %d and inside the %d variables)", a,
                rows, first, row - 1, nvars);
        while (row < first) m->first3[k++] = row++;  /* the scalars before it */
        for (int r = first; r < first + rows; r++)
            if (m->vars[2 * r] == MBS_V_METHOD) BAD("corrupt array table (array %d holds a String)", a);
        if (rows) m->first3[k++] = first, row = first + rows;
    }
    m->nvars3 = k;
    m->first3[k] = nvars;
    return 0;
}

MbsModel *mbs_model_load(const void *bytes, size_t len, char *err, size_t errlen)
{
    MbsModel *m = calloc(1, sizeof *m);
    unsigned char *b = NULL;
    if (!m) { snprintf(err, errlen, "out of memory"); return NULL; }
    if (!bytes || len < FH_SIZE || memcmp(bytes, MBS_SCENE_MAGIC, 4)) FAIL("not a compiled mbsfmu scene (bad magic)");
    int32_t version, nsec;
    memcpy(&version, (const char *)bytes + FH_VERSION, 4);
    if (version != MBS_FORMAT_VERSION)
        FAIL("compiled scene has format version %d, this engine reads version %d: rebuild the FMU with the "
             "same mbsfmu version as its engine", (int)version, MBS_FORMAT_VERSION);
    b = malloc(len);
    if (!b) FAIL("out of memory");
    memcpy(b, bytes, len);
    m->blob = b;
    memcpy(m->guid, b + FH_GUID, sizeof m->guid - 1);
    m->guid[sizeof m->guid - 1] = 0;
    memcpy(&nsec, b + FH_NSEC, 4);
    if (nsec < 1 || nsec > MBS_MAX_SECTIONS || FH_SIZE + (size_t)nsec * SR_SIZE > len) FAIL("corrupt section table");
    Section tab[MBS_MAX_SECTIONS];
    memcpy(tab, b + FH_SIZE, (size_t)nsec * SR_SIZE);
    const int32_t *h = section(b, len, tab, nsec, S_HEADER, 0, H_SIZE, NULL);
    if (!h) FAIL("missing header");
    memcpy(m->hdr, h, sizeof m->hdr);
    const int32_t *H = m->hdr;
    if (check_header(H, err, errlen)) goto fail;
    m->dense = mbs_dense_path(H);
    m->stride = m->dense ? W_SIZE(H[H_NVEL]) : AB_SIZE;
    const int nb = H[H_NB], np = H[H_NPOS], nv = H[H_NVEL];
    int ne_i = 0, ne_d = 0;
#define SEC(ptr, id, kind, want) if (!(ptr = section(b, len, tab, nsec, id, kind, want, NULL))) FAIL("missing or corrupt section %d", id)
    SEC(m->ib, S_BODY_I, 0, (int64_t)nb * IB);
    SEC(m->iforce, S_FORCE_I, 0, (int64_t)H[H_NFORCE] * IF);
    SEC(m->quat, S_QUAT, 0, (int64_t)H[H_NQUAT] * 7);
    SEC(m->plain, S_PLAIN, 0, 2 * (int64_t)H[H_NPLAIN]);
    SEC(m->vars, S_VARS, 0, 2 * (int64_t)H[H_NVARS]);
    SEC(m->out, S_OUT_I, 0, 3 * (int64_t)H[H_NOUT]);
    SEC(m->prog, S_PROG, 0, 4 * (int64_t)H[H_NPROG]);
    SEC(m->code, S_CODE, 0, H[H_NCODE]);
    SEC(m->D, S_D, 1, H[H_ND]);
    for (int k = 0; k < np + nv; k++)  /* a host divides by them (its error weights): positive and finite */
        if (!(m->D[H[H_D_NOMINAL] + k] > 0 && isfinite(m->D[H[H_D_NOMINAL] + k])))
            FAIL("corrupt nominal of continuous state %d (%g, a positive number)", k, m->D[H[H_D_NOMINAL] + k]);
    m->elastic_i = section(b, len, tab, nsec, S_ELASTIC_I, 0, -1, &ne_i);
    m->elastic_d = section(b, len, tab, nsec, S_ELASTIC_D, 1, -1, &ne_d);
    m->n_elastic_i = m->elastic_i ? ne_i : 0;
    m->n_elastic_d = m->elastic_d ? ne_d : 0;
    m->stress_i = section(b, len, tab, nsec, S_STRESS_I, 0, -1, &m->nstress);  /* absent: no stress nodes */
    m->stress_d = section(b, len, tab, nsec, S_STRESS_D, 1, -1, &m->n_stress_d);
    if (!m->stress_i || !m->stress_d) m->nstress = m->n_stress_d = 0;  /* (a broken one: its variables fail) */
    if (m->nstress % 2) FAIL("corrupt stress section");
    m->nstress /= 2;
    if (m->nstress && !(H[H_FEATURES] & F_ELASTIC)) FAIL("corrupt stress section (stress nodes in a scene without elastic bodies)");
    SEC(m->vdom, S_VDOM, 1, 3 * (MBS_V_STEP + 1));
    m->rules = section(b, len, tab, nsec, S_RULES, 0, -1, &m->nrules);
    m->rule_names = section(b, len, tab, nsec, S_RULE_NAMES, 2, -1, &m->n_rule_names);
    SEC(m->limits, S_LIMITS, 1, LIM_N);
    if (!m->rules || !m->rule_names) m->nrules = m->n_rule_names = 0;
    if (m->nrules % 3) FAIL("corrupt rule table");
    m->nrules /= 3;
    if (check_bodies(m, err, errlen) || check_forces(m, err, errlen) || check_tables(m, err, errlen)) goto fail;
    int nnames = 0;
    const char *names = section(b, len, tab, nsec, S_NAMES, 2, -1, &nnames);
    const size_t nstr = (size_t)np + (size_t)nb + (size_t)H[H_NVARS];
    if (nstr > (size_t)nnames) FAIL("corrupt name table (%zu names needed)", nstr);  /* one byte each at least */
    m->coord_name = calloc(nstr + 1, sizeof(char *));
    int32_t *read = malloc(((size_t)H[H_NVARS] + 1) * sizeof *read);
    m->read = read;
    if (!m->coord_name || !read) FAIL("out of memory");
    for (int k = 0; k < H[H_NVARS]; k++) {
        const int kind = m->vars[2 * k], idx = m->vars[2 * k + 1];
        read[k] = kind == MBS_V_Y ? idx : kind == MBS_V_YD ? np + idx : kind == MBS_V_OUT ? np + nv + idx : -1;
    }
    m->body_name = m->coord_name + np;
    m->var_name = m->body_name + nb;
    for (size_t k = 0, pos = 0; k < nstr; k++) {
        const char *end = pos < (size_t)nnames ? memchr(names + pos, 0, (size_t)nnames - pos) : NULL;
        if (!end) FAIL("corrupt name table");
        m->coord_name[k] = names + pos;
        pos = (size_t)(end - names) + 1;
    }
    int narrays = 0;
    const int32_t *arrays = section(b, len, tab, nsec, S_ARRAYS, 0, -1, &narrays);
    if (fmi3_variables(m, arrays, narrays, err, errlen)) goto fail;
#ifdef MBS_WITH_EXPR
    if (mbs_validate_code(m, err, errlen)) goto fail;
#else
    if (H[H_NPROG] > 0) FAIL("the scene has expressions but this engine was built without them (rebuild the FMU)");
#endif
    if (check_rules_table(m, err, errlen)) goto fail;
#ifdef MBS_WITH_ELASTIC
    if ((H[H_FEATURES] & F_ELASTIC) && mbs_elastic_validate(m, err, errlen)) goto fail;
#endif
    if (!m->dense && check_owners(m, err, errlen)) goto fail;  /* the recursive path reads each coordinate once */
    if (H[H_FEATURES] & F_ELASTIC) {
        const int ne = m->elastic_i[EH_NE];
        m->flexed = malloc((size_t)nb + 1);
        m->elastic_block = malloc(((size_t)ne + 1) * sizeof *m->elastic_block);
        if (!m->flexed || !m->elastic_block) FAIL("out of memory");
        for (int i = 0; i < nb; i++) {  /* (parents first: check_bodies) */
            const MbsBodyI *bi = mbs_body_i(m, i);
            m->flexed[i] = bi->node >= 0 || (bi->parent >= 0 && m->flexed[bi->parent]);
        }
        m->elastic_block[0] = 0;
        for (int el = 0; el < ne; el++) {  /* (rows validated: 1 ≤ n ≤ MAX_MODES) */
            const size_t n = (size_t)m->elastic_i[EH + EI * el + EI_N];
            m->elastic_block[el + 1] = m->elastic_block[el] + n * (n + 9);
        }
    }
    return m;
fail:
    free((void *)m->read);
    free(m->first3);
    free(m->flexed);
    free(m->elastic_block);
    free(m->coord_name);
    free(b);
    free(m);
    return NULL;
}

MbsModel *mbs_model_load_file(const char *path, char *err, size_t errlen)
{
    size_t len = 0;
    void *buf = mbs_read_regular(path, MBS_SCENE_FILE_LIMIT, &len, err, errlen);  /* regular files only, bounded */
    MbsModel *m = buf ? mbs_model_load(buf, len, err, errlen) : NULL;
    free(buf);
    return m;
}

void mbs_model_free(MbsModel *m)
{
    if (!m) return;
    free((void *)m->read);
    free(m->first3);
    free(m->flexed);
    free(m->elastic_block);
    free(m->coord_name);
    free(m->blob);
    free(m);
}

const char *mbs_model_guid(const MbsModel *m) { return m->guid; }
int mbs_model_nvars(const MbsModel *m) { return m->hdr[H_NVARS]; }
int mbs_model_nvars3(const MbsModel *m) { return m->nvars3; }
int mbs_model_var3(const MbsModel *m, unsigned vr3, int *rows)
{
    if (vr3 >= (unsigned)m->nvars3) return -1;
    *rows = m->first3[vr3 + 1] - m->first3[vr3];
    return m->first3[vr3];
}
int mbs_model_var_kind(const MbsModel *m, int vr) { return vr >= 0 && vr < m->hdr[H_NVARS] ? m->vars[2 * vr] : -1; }
const char *mbs_model_var_name(const MbsModel *m, int vr) { return vr >= 0 && vr < m->hdr[H_NVARS] ? m->var_name[vr] : NULL; }

const char *mbs_var_name_of(const MbsModel *m, int kind, int index)
{
    for (int vr = 0; vr < m->hdr[H_NVARS]; vr++)
        if (m->vars[2 * vr] == kind && m->vars[2 * vr + 1] == index) return m->var_name[vr];
    return "?";
}
int mbs_model_npos(const MbsModel *m) { return NPOS(m); }
int mbs_model_nvel(const MbsModel *m) { return NVEL(m); }
