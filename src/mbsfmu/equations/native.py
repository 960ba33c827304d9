"""The compiled right-hand side of rigid trees (native.c): tables packed from a bound Model, called by ctypes.

Why: the numpy recursion in tree.py spends 60–220 µs per call on Python overhead for 1–6 bodies; the same
recursion in C takes a few µs. tree.py stays the readable reference (and the path for elastic scenes);
tests check that both agree, and both against Pinocchio.

The shared library is compiled from native.c with the system C compiler on first use and cached
(``$MBSFMU_CACHE`` or ``~/.cache/mbsfmu``); an FMU carries its own copy next to this module. Without a
compiler, or with ``MBSFMU_NATIVE=0``, everything runs on the numpy path.
"""

import ctypes
import hashlib
import os
import subprocess
import sys
import sysconfig
import tempfile
import warnings
from pathlib import Path

import numpy as np

SOURCE = Path(__file__).with_name("native.c")
CFLAGS = ("-O3", "-fPIC", "-shared", "-std=c99")
JOINT_TYPES = {("fixed", None): 0, ("revolute", None): 1, ("prismatic", None): 2, ("cylindrical", None): 3,
               ("universal", None): 4, ("planar", None): 5, ("spherical", "quaternion"): 6,
               ("spherical", "cardan"): 7, ("free", "quaternion"): 8, ("free", "cardan"): 9}
FORCE_TYPES = {"joint_spring_damper": 0, "spring_damper": 1, "force": 2, "torque": 3}
# table layouts, mirrored from native.c
IB_PARENT, IB_JTYPE, IB_NPOS, IB_NVEL, IB_MASSIVE, IB_POS, IB_VEL, IB_DRV, IB = 0, 1, 2, 3, 4, 5, 12, 18, 25
DB_A1, DB_A2, DB_AT, DB_R0, DB_M, DB_C, DB_I, DB = 0, 3, 6, 9, 18, 19, 22, 31
IF_TYPE, IF_A, IF_B, IF_FRAME, IF = 0, 1, 2, 3, 4
DF_K, DF_D, DF_L, DF_AT_A, DF_AT_B, DF_VEC, DF = 0, 1, 2, 3, 6, 9, 12

_P = ctypes.c_void_p


class _Tree(ctypes.Structure):
    _fields_ = [(n, ctypes.c_int) for n in ("nb", "npos", "nvel", "nforce", "nquat", "nplain", "has_gravity", "ndrv", "nvec")] + \
               [(n, _P) for n in ("ib", "db", "iforce", "dforce", "g", "quat", "plain_pos", "plain_vel", "vec_rows",
                                  "td", "x", "q_in", "work", "M", "k", "q", "xdot")]


# ------------------------------------------------------------------------------------------ library
_lib = None


def _library_name():
    tag = hashlib.sha256(SOURCE.read_bytes() + " ".join(CFLAGS).encode() + sys.platform.encode()).hexdigest()[:16]
    # a versioned name (.so.1): importers and pkgutil must not mistake it for a Python extension module
    return f"libmbsfmu_native_{tag}{sysconfig.get_config_var('SHLIB_SUFFIX') or '.so'}.1"


def compile_library(dest_dir):
    """Compile native.c into dest_dir (atomic rename, safe for concurrent processes); returns the path."""
    dest_dir = Path(dest_dir)
    dest_dir.mkdir(parents=True, exist_ok=True)
    out = dest_dir / _library_name()
    if out.exists():
        return out
    cc = os.environ.get("CC") or "cc"
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=dest_dir)
    os.close(fd)
    try:
        subprocess.run([cc, *CFLAGS, "-o", tmp, str(SOURCE), "-lm"], check=True, capture_output=True, text=True)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


def library_path():
    """Path of the compiled kernel: an FMU's own copy next to this module, else the per-user cache
    (compiled on first use). Raises OSError or CalledProcessError when it cannot be had."""
    shipped = Path(__file__).with_name(_library_name())
    if shipped.exists():
        return shipped
    cache = Path(os.environ.get("MBSFMU_CACHE") or Path.home() / ".cache" / "mbsfmu")
    try:
        return compile_library(cache)
    except PermissionError:  # read-only home (some CI runners, containers): a per-user temporary directory
        return compile_library(Path(tempfile.gettempdir()) / f"mbsfmu-{os.getuid() if hasattr(os, 'getuid') else 0}")


def library():
    """The loaded kernel, or None (numpy path) when disabled or no compiler is available."""
    global _lib
    if _lib is not None or os.environ.get("MBSFMU_NATIVE", "1") == "0":
        return _lib or None
    try:
        lib = ctypes.CDLL(str(library_path()))
    except (OSError, subprocess.CalledProcessError) as exc:
        detail = (getattr(exc, "stderr", "") or str(exc)).strip()
        warnings.warn(f"mbsfmu: compiled right-hand side unavailable ({detail}); using the numpy path (slower)")
        _lib = False
        return None
    for fn in (lib.mbs_rhs, lib.mbs_equations, lib.mbs_kinematics):
        fn.argtypes, fn.restype = [ctypes.POINTER(_Tree)], ctypes.c_int
    lib.mbs_erk_stages.argtypes = [ctypes.POINTER(_Tree), ctypes.c_int, ctypes.c_int, _P, ctypes.c_int,
                                   ctypes.c_double, _P, _P, _P, _P]
    lib.mbs_erk_stages.restype = ctypes.c_int
    _lib = lib
    return lib


def supports(model):
    """True for rigid scenes (elastic bodies stay on the numpy path)."""
    return not model.has_elastic


# ------------------------------------------------------------------------------------------ binding
class NativeTree:
    """A Model's tables in the layout of native.c, its workspace, and the calls into the kernel."""

    def __init__(self, model, lib):
        self.model, self.lib = model, lib
        f, nb = model.nvel, len(model.bodies)
        self.x = np.zeros(model.npos + model.nvel)
        self.q_in = np.zeros(f)
        self.work = np.zeros(nb * (26 + 6 * f) + 6 * f)  # per body see W_* in native.c, then scratch
        self.M, self.k, self.q = np.zeros((f, f)), np.zeros(f), np.zeros(f)
        self.xdot = np.zeros(model.npos + model.nvel)
        self.xs = np.zeros(model.npos + model.nvel)  # argument of the last Runge–Kutta stage
        self._x_ptr, self._xs_ptr, self._pointers = self.x.ctypes.data, self.xs.ctypes.data, {}
        self.quat = np.array([np.r_[p, w] for p, w in zip(model.quaternions, model.quat_vel)], dtype=np.intc).reshape(-1, 7)
        self.plain_pos = np.ascontiguousarray(model.plain_pos, dtype=np.intc)
        self.plain_vel = np.ascontiguousarray(model.plain_vel, dtype=np.intc)
        self.drives = [d for b in model.bodies for d in b.drives]
        self.bind()

    def bind(self):
        """Pack the numbers of the (re)bound model."""
        m = self.model
        nb = len(m.bodies)
        ib = np.full((nb, IB), -1, dtype=np.intc)
        db = np.zeros((nb, DB))
        slot = 0
        for i, b in enumerate(m.bodies):
            j = b.joint
            ib[i, IB_PARENT], ib[i, IB_JTYPE] = b.parent, JOINT_TYPES[(b.kind, b.param if b.kind in ("spherical", "free") else None)]
            ib[i, IB_NPOS], ib[i, IB_NVEL] = j.npos, j.nvel
            ib[i, IB_MASSIVE] = int(i in m.massive)
            ib[i, IB_POS:IB_POS + j.npos] = b.pos_idx
            ib[i, IB_VEL:IB_VEL + j.nvel] = b.vel_idx
            for k, *_ in b.drives:
                ib[i, IB_DRV + k] = slot
                slot += 1
            axes = getattr(j, "a", None), getattr(j, "a1", getattr(j, "ax", None)), getattr(j, "a2", getattr(j, "ay", None))
            if axes[0] is not None:
                db[i, DB_A1:DB_A1 + 3] = axes[0]
            elif axes[1] is not None:
                db[i, DB_A1:DB_A1 + 3], db[i, DB_A2:DB_A2 + 3] = axes[1], axes[2]
            if b.at is not None:
                db[i, DB_AT:DB_AT + 3] = b.at
            db[i, DB_R0:DB_R0 + 9] = (b.R0 if b.R0 is not None else np.eye(3)).ravel()
            db[i, DB_M] = b.m
            if b.c is not None:
                db[i, DB_C:DB_C + 3] = b.c
            db[i, DB_I:DB_I + 9] = b.I.ravel()
        forces = m.bound_forces
        iforce = np.zeros((max(1, len(forces)), IF), dtype=np.intc)
        dforce = np.zeros((max(1, len(forces)), DF))
        self._vector_forces = []  # (row, element) whose vector depends on t or on inputs
        for e, fe in enumerate(forces):
            kind = fe["type"]
            iforce[e, IF_TYPE] = FORCE_TYPES[kind]
            if kind == "joint_spring_damper":
                iforce[e, IF_A], iforce[e, IF_B] = fe["pos_index"], fe["vel_index"]
                dforce[e, [DF_K, DF_D, DF_L]] = fe["stiffness"], fe["damping"], fe["offset"]
            elif kind == "spring_damper":
                iforce[e, IF_A], iforce[e, IF_B] = fe["body_index"]
                dforce[e, [DF_K, DF_D, DF_L]] = fe["stiffness"], fe["damping"], fe["length"]
                dforce[e, DF_AT_A:DF_AT_A + 3], dforce[e, DF_AT_B:DF_AT_B + 3] = fe["at"]
            else:
                iforce[e, IF_A], iforce[e, IF_FRAME] = fe["body_index"], int(fe["frame"] == "body")
                if kind == "force":
                    dforce[e, DF_AT_A:DF_AT_A + 3] = fe["at"]
                if "input" not in fe and fe["constant"] is not None:
                    dforce[e, DF_VEC:DF_VEC + 3] = fe["constant"]
                else:
                    self._vector_forces.append((e, fe))
        self.ib, self.db, self.iforce, self.dforce = ib, db, iforce, dforce
        self.autonomous = not self.drives and all("input" in fe for _, fe in self._vector_forces)
        # time-dependent numbers (td): p, v, a per drive, then the vectors of _vector_forces; row 0 for
        # single calls, one row per Runge–Kutta stage for mbs_erk_stages (16 rows: DOP853's extended tableau)
        self.ntd = 3 * (len(self.drives) + len(self._vector_forces))
        self.td = np.zeros((16, max(1, self.ntd)))
        self.vec_rows = np.array([e for e, _ in self._vector_forces] or [0], dtype=np.intc)
        self.g = np.array(m.g if m.g is not None else np.zeros(3), dtype=float)
        arrays = dict(ib=ib, db=db, iforce=iforce, dforce=dforce, g=self.g, quat=self.quat, plain_pos=self.plain_pos,
                      plain_vel=self.plain_vel, vec_rows=self.vec_rows, td=self.td, x=self.x, q_in=self.q_in, work=self.work, M=self.M, k=self.k,
                      q=self.q, xdot=self.xdot)
        for a in arrays.values():
            assert a.flags.c_contiguous
        self.tree = _Tree(nb=nb, npos=m.npos, nvel=m.nvel, nforce=len(forces), nquat=len(self.quat),
                          nplain=len(self.plain_pos), has_gravity=int(m.g is not None), ndrv=len(self.drives),
                          nvec=len(self._vector_forces),
                          **{k: a.ctypes.data for k, a in arrays.items()})
        self._ref = ctypes.byref(self.tree)

    def _time_dependent(self, t, F_in, row):
        """Drive values and force vectors at time t into one row of td."""
        env = self.model.env
        env["t"] = t
        for s, (_, f, fd, fdd) in enumerate(self.drives):
            row[3 * s:3 * s + 3] = f(env), fd(env), fdd(env)
        k = 3 * len(self.drives)
        for _, fe in self._vector_forces:
            if "input" in fe:
                vec = F_in.get(fe["input"]) if F_in else None
                row[k:k + 3] = 0.0 if vec is None else vec
            else:
                row[k:k + 3] = [v(env) for v in fe["value"]]
            k += 3

    def _load(self, x, t, q_in, F_in, td=True):
        """Copy the state, the inputs and (td) the numbers at time t into the kernel's buffers."""
        self.x[:] = x
        if q_in is None:
            self.q_in.fill(0.0)
        else:
            self.q_in[:] = q_in
        if td and self.ntd:
            self._time_dependent(t, F_in, self.td[0])

    def stages(self, A, C, K, i0, s, h, x, t, t_end, q_in, F_in):
        """Runge–Kutta stages K[i0:s] in one compiled call (stage times t + c_i h, t_end where c_i = 1):
        returns (status, argument of the last stage); status 1: M singular, 2: gimbal lock there."""
        self._load(x, t, q_in, F_in, td=self.autonomous)  # otherwise every stage gets its own td row below
        td = None
        if not self.autonomous:
            td = self._pointer(self.td)
            for i in range(i0, s):
                self._time_dependent(t_end if C[i] == 1.0 else t + C[i] * h, F_in, self.td[i])
        rc = self.lib.mbs_erk_stages(self._ref, i0, s, self._pointer(A), A.shape[1], h, self._x_ptr,
                                     self._pointer(K), self._xs_ptr, td)
        return rc, self.xs.copy()

    def _pointer(self, a):
        """Data address of a long-lived array (tableaus, stage buffers), looked up once: ndarray.ctypes
        costs about 1 µs per access. The cache keeps the array alive, so its id cannot be reused."""
        hit = self._pointers.get(id(a))
        if hit is None or hit[0] is not a:
            if len(self._pointers) > 64:
                self._pointers.clear()
            hit = self._pointers[id(a)] = (a, a.ctypes.data)
        return hit[1]

    def rhs(self, t, x, q_in=None, F_in=None):
        """ẋ = [Z(y) ẏ; M⁻¹(q − k)], or None when M is not positive definite."""
        self._load(x, t, q_in, F_in)
        if self.lib.mbs_rhs(self._ref):
            return None
        return self.xdot.copy()

    def frames(self, x, t):
        """Per body (S, o, ω, v) of its origin at state x: views into the workspace, valid until the next call."""
        self._load(x, t, None, None)
        self.lib.mbs_kinematics(self._ref)
        W = self.work[:len(self.model.bodies) * (26 + 6 * self.model.nvel)].reshape(len(self.model.bodies), -1)
        return [(w[:9].reshape(3, 3), w[9:12], w[12:15], w[15:18]) for w in W]

    def equations(self, y, yd, t, q_in=None, F_in=None):
        """M, k, q (copies)."""
        self._load(np.concatenate([y, yd]), t, q_in, F_in)
        self.lib.mbs_equations(self._ref)
        return self.M.copy(), self.k.copy(), self.q.copy()


def native_tree(model):
    """NativeTree for the model, or None when the scene or the machine needs the numpy path."""
    if not supports(model):
        return None
    lib = library()
    return NativeTree(model, lib) if lib is not None else None
