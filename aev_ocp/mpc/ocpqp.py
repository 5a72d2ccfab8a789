"""ctypes binding of aev_ocp's structure-exploiting QP solver (``aev_ocp/c/ocp_qp.c``, interface in
``ocp_qp.h``): a primal-dual interior point (Mehrotra predictor-corrector) whose Newton systems are
solved by a Riccati recursion over the stages.

The QP, stage k = 0..N-1 with w_k = (x_k, u_k) (nb = nx + nu) and the terminal w_N = x_N::

    min  sum_k 1/2 w_k' H_k w_k + g_k' w_k + 1/2 x_N' H_N x_N + g_N' x_N
    s.t. x_{k+1} = E_k w_k + e_k,  x_0 = x0,  lbw <= w <= ubw,  lc <= C_k w_k <= uc

The QP must be convex: its reduced Hessian (on the null space of the dynamics, x_0 fixed) positive definite;
the blocks H_k may be indefinite (an exact Hessian). Otherwise the status is 'factorization' or 'max_iter',
unless the iterate ends at a vertex where the barrier terms make the Newton matrices positive definite (then
'ok' with that vertex, a local minimiser). Safeguards against the stall of Mehrotra's method on degenerate rows (ocp_qp.c): a wide
neighbourhood step rule and Gondzio's centrality correctors. Termination: every residual below its
tolerance (complementarity: the mean of s z); on degenerate rows w is then O(sqrt(tol)) from the exact
solution (up to 1e-4 at 1e-9 on the MPC's QPs, 4e-8 at 1e-12).

Multipliers follow CasADi's convention (``ca.conic``: lam > 0 on an active upper bound, < 0 on an
active lower one); ``pi`` are the dynamics multipliers (Lagrangian term pi_k'(E_k w_k + e_k - x_{k+1})).
Bounds with |value| >= 1e19 (and +-inf) are absent. The library is compiled once per process into the
private cache (:func:`aev_ocp.compiled.compile_shared`); no C compiler raises :class:`OcpQPError`.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..params import ParameterError

__all__ = [
    "OcpQP",
    "OcpQPDims",
    "OcpQPSettings",
    "OcpQPResult",
    "OcpQPError",
    "STATUS",
    "INF",
    "BACKENDS",
    "HPIPM_MODES",
    "hpipm_library",
]

INF = 1e19  # OCPQP_INF: a bound at least this large in magnitude is absent
#: ocp_qp.h's statuses; 6 'acceptable': not converged, the returned iterate is the best one with every residual
#: within 100x its tolerance (OCPQP_ACCEPT_FACTOR), as IPOPT's acceptable level
STATUS = {0: "ok", 1: "max_iter", 2: "factorization", 3: "nonfinite", 4: "infeasible", 5: "bad_dims", 6: "acceptable"}


class OcpQPError(ParameterError):
    """The QP solver library cannot be built or the solver cannot be created (names the cause)."""


@dataclass(frozen=True)
class OcpQPDims:
    """Horizon N (>= 1), states nx (>= 1), controls nu (>= 0), general rows per stage nc and at the end ncN."""

    N: int
    nx: int
    nu: int
    nc: int = 0
    ncN: int = 0

    def __post_init__(self) -> None:
        for name, low in (("N", 1), ("nx", 1), ("nu", 0), ("nc", 0), ("ncN", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ParameterError(f"OcpQPDims.{name} must be an integer >= {low}, got {v!r}")

    @property
    def nb(self) -> int:
        return self.nx + self.nu

    @property
    def nw(self) -> int:
        """Length of the stacked (x_0, u_0, ..., x_N)."""
        return self.N * self.nb + self.nx


@dataclass(frozen=True)
class OcpQPSettings:
    """Iteration limit and tolerances (absolute, inf-norm; complementarity: mean of s*z); defaults of ocp_qp.h."""

    max_iter: int = 50
    tol_stat: float = 1e-10
    tol_eq: float = 1e-10
    tol_ineq: float = 1e-10
    tol_comp: float = 1e-10
    reg_prim: float = 1e-12  # static regularisation of the control block of the Riccati factorisation

    def __post_init__(self) -> None:
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, (int, np.integer)) or self.max_iter < 0:
            raise ParameterError(f"OcpQPSettings.max_iter must be an integer >= 0, got {self.max_iter!r}")
        for name in ("tol_stat", "tol_eq", "tol_ineq", "tol_comp", "reg_prim"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise ParameterError(f"OcpQPSettings.{name} must be a finite number >= 0, got {v!r}")


@dataclass
class OcpQPResult:
    """Solution (stacked like the data), status (0 = ok, see :data:`STATUS`), iterations and final residuals."""

    w: np.ndarray
    pi: np.ndarray
    lam_w: np.ndarray
    lam_c: np.ndarray
    status: int
    iterations: int
    residuals: dict[str, float] = field(default_factory=dict)

    @property
    def status_name(self) -> str:
        return STATUS.get(self.status, f"unknown({self.status})")

    @property
    def ok(self) -> bool:
        return self.status == 0


class _Dims(ctypes.Structure):
    _fields_ = [(n, ctypes.c_int) for n in ("N", "nx", "nu", "nc", "ncN")]


class _Settings(ctypes.Structure):
    _fields_ = [("max_iter", ctypes.c_int)] + [
        (n, ctypes.c_double) for n in ("tol_stat", "tol_eq", "tol_ineq", "tol_comp", "reg_prim")
    ]


_DATA_FIELDS = ("H", "g", "E", "e", "C", "lc", "uc", "lbw", "ubw", "x0")


class _Data(ctypes.Structure):
    _fields_ = [(n, ctypes.c_void_p) for n in _DATA_FIELDS]


class _Info(ctypes.Structure):
    _fields_ = [("iterations", ctypes.c_int), ("status", ctypes.c_int)] + [
        (n, ctypes.c_double) for n in ("res_stat", "res_eq", "res_ineq", "res_comp")
    ]


_LIBS: dict[tuple[tuple[int, ...] | None, str | None], ctypes.CDLL] = {}

#: The QP backends of the interface ocp_qp.h: 'ocp_qp' (aev_ocp/c/ocp_qp.c, ours: the default; see
#: benchmarks/bench_ocp_qp.py) and 'hpipm' (aev_ocp/c/ocp_qp_hpipm.c: HPIPM's C API, the libhpipm.so that the
#: casadi wheel ships).
BACKENDS = ("ocp_qp", "hpipm")
#: HPIPM's modes (d_ocp_qp_ipm_arg_set_default; values of enum hpipm_mode in hpipm_common.h).
HPIPM_MODES = {"speed": 1, "balance": 2, "robust": 3}
_HPIPM_LIB: list[Any] = []  # [CDLL] once built, [str] the reason it cannot be


def hpipm_paths() -> tuple[Path, Path] | str:
    """(the folder with libhpipm.so and libblasfeo.so, the folder with their headers) of the installed casadi
    wheel, or why not (one line)."""
    try:
        import casadi
    except ImportError:  # pragma: no cover - casadi is a dependency
        return "casadi is not installed"
    root = Path(casadi.__file__).resolve().parent
    inc = root / "include"
    if not (root / "libhpipm.so").exists() or not (root / "libblasfeo.so").exists():
        return f"the casadi wheel at {root} ships no libhpipm.so/libblasfeo.so"
    if not (inc / "hpipm_d_ocp_qp_ipm.h").exists():
        return f"the casadi wheel at {root} ships no HPIPM headers (include/hpipm_d_ocp_qp_ipm.h)"
    return root, inc


def hpipm_library() -> ctypes.CDLL | str:
    """The HPIPM backend (aev_ocp/c/ocp_qp_hpipm.c linked with the casadi wheel's libhpipm.so), built once per
    process into the private cache, or why it cannot be built or loaded (one line)."""
    if _HPIPM_LIB:
        return _HPIPM_LIB[0]
    where = hpipm_paths()
    if isinstance(where, str):
        _HPIPM_LIB.append(where)
        return where
    root, inc = where
    from ..compiled import compile_shared

    folder = resources.files("aev_ocp").joinpath("c")
    src = folder.joinpath("ocp_qp_hpipm.c").read_text(encoding="utf-8")
    flags = ("-std=c99", f"-I{inc}", "-Wl,--no-as-needed", f"-L{root}", "-lhpipm", "-lblasfeo", f"-Wl,-rpath,{root}")
    built = compile_shared(
        src,
        "ocp_qp_hpipm",
        "ocpqp",
        extra_flags=flags,
        companions={"ocp_qp.h": folder.joinpath("ocp_qp.h").read_text(encoding="utf-8")},
    )
    if built.path is None:
        _HPIPM_LIB.append(f"ocp_qp_hpipm.c cannot be built against {root}: {built.error}")
        return _HPIPM_LIB[0]
    try:
        lib = ctypes.CDLL(str(built.path))
    except OSError as exc:
        _HPIPM_LIB.append(f"the HPIPM backend does not load: {str(exc)[:200]}")
        return _HPIPM_LIB[0]
    _declare(lib)
    lib.ocpqp_hpipm_create.restype = ctypes.c_void_p
    lib.ocpqp_hpipm_create.argtypes = [ctypes.POINTER(_Dims), ctypes.POINTER(_Settings), ctypes.c_int]
    lib.ocpqp_hpipm_unsupported.restype = ctypes.c_int
    lib.ocpqp_hpipm_unsupported.argtypes = [ctypes.POINTER(_Dims)]
    _HPIPM_LIB.append(lib)
    return lib


def _declare(lib: ctypes.CDLL) -> None:
    """Argument and result types of the ocp_qp.h interface (every backend)."""
    lib.ocpqp_create.restype = ctypes.c_void_p
    lib.ocpqp_create.argtypes = [ctypes.POINTER(_Dims), ctypes.POINTER(_Settings)]
    lib.ocpqp_free.restype = None
    lib.ocpqp_free.argtypes = [ctypes.c_void_p]
    lib.ocpqp_solve.restype = ctypes.c_int
    solve_args: list[Any] = [ctypes.c_void_p, ctypes.POINTER(_Data), *[ctypes.c_void_p] * 4, ctypes.POINTER(_Info)]
    lib.ocpqp_solve.argtypes = solve_args
    lib.ocpqp_solve_warm.restype = ctypes.c_int
    lib.ocpqp_solve_warm.argtypes = [*solve_args[:2], *[ctypes.c_void_p] * 4, *solve_args[2:]]


def source_files() -> dict[str, str]:
    """The solver's C sources (package data): {'ocp_qp.c': ..., 'ocp_qp.h': ...}."""
    folder = resources.files("aev_ocp").joinpath("c")
    return {n: folder.joinpath(n).read_text(encoding="utf-8") for n in ("ocp_qp.c", "ocp_qp.h")}


def library(fixed: tuple[int, int, int, int] | None = None, source: str | None = None) -> ctypes.CDLL:
    """The compiled solver (built once per process into the private cache); ``fixed`` = (nx, nu, nc, ncN)
    compiles those dimensions in as constants (-DOCPQP_NX=... : faster, and only for those dimensions);
    ``source``: the text of another ocp_qp.c with the same interface (benchmarks: an older version in the
    same process)."""
    lib = _LIBS.get((fixed, source))
    if lib is None:
        from ..compiled import compile_shared

        src = source_files()
        if source is not None:
            src["ocp_qp.c"] = source
        flags = (
            ("-std=c99",)
            if fixed is None
            else ("-std=c99", *(f"-DOCPQP_{n}={v}" for n, v in zip(("NX", "NU", "NC", "NCN"), fixed)))
        )
        built = compile_shared(
            src["ocp_qp.c"], "ocp_qp", "ocpqp", extra_flags=flags, companions={"ocp_qp.h": src["ocp_qp.h"]}
        )
        if built.path is None:
            raise OcpQPError(f"the OCP QP solver cannot be built: {built.error}")
        lib = ctypes.CDLL(str(built.path))
        _declare(lib)
        _LIBS[(fixed, source)] = lib
    return lib


def _pack(name: str, value: Any, shapes: Sequence[tuple[int, int]]) -> np.ndarray:
    """A flat column-major float64 array of the blocks of ``shapes``, from the flat array itself or a
    sequence of 2-D blocks (or vectors for (n, 1) shapes); ParameterError naming ``name`` otherwise."""
    total = sum(r * c for r, c in shapes)
    if isinstance(value, np.ndarray) and value.ndim == 1 or np.isscalar(value):
        arr = np.ascontiguousarray(value, dtype=float).reshape(-1)
        if arr.size != total:
            raise ParameterError(f"{name} must have {total} entries (the stacked stage blocks), got {arr.size}")
        return arr
    try:
        blocks = list(value)
    except TypeError:
        raise ParameterError(
            f"{name} must be a flat array of {total} entries or a sequence of "
            f"{len(shapes)} blocks, got {type(value).__name__}"
        ) from None
    if len(blocks) != len(shapes):
        raise ParameterError(f"{name} must have {len(shapes)} stage blocks, got {len(blocks)}")
    out = np.empty(total)
    pos = 0
    for k, (blk, (r, c)) in enumerate(zip(blocks, shapes)):
        a = np.asarray(blk, dtype=float)
        if a.ndim == 1 and c == 1:
            a = a.reshape(-1, 1)
        if a.size == 0 and r * c == 0:
            continue
        if a.shape != (r, c):
            raise ParameterError(f"{name}[{k}] must have shape {(r, c)}, got {a.shape}")
        out[pos : pos + r * c] = a.reshape(-1, order="F")
        pos += r * c
    return out


def _block_shapes(d: OcpQPDims) -> dict[str, list[tuple[int, int]]]:
    """Shapes of each data argument's stage blocks."""
    N, nx, nb, nc, ncN = d.N, d.nx, d.nb, d.nc, d.ncN
    return {
        "H": [(nb, nb)] * N + [(nx, nx)],
        "g": [(nb, 1)] * N + [(nx, 1)],
        "E": [(nx, nb)] * N,
        "e": [(nx, 1)] * N,
        "C": [(nc, nb)] * N + [(ncN, nx)],
        "lc": [(nc, 1)] * N + [(ncN, 1)],
        "uc": [(nc, 1)] * N + [(ncN, 1)],
        "lbw": [(nb, 1)] * N + [(nx, 1)],
        "ubw": [(nb, 1)] * N + [(nx, 1)],
        "x0": [(nx, 1)],
    }


class OcpQP:
    """One solver instance (its memory allocated once in C) for fixed dimensions; see the module docstring."""

    def __init__(
        self,
        dims: OcpQPDims,
        settings: OcpQPSettings | None = None,
        specialise: bool = False,
        source: str | None = None,
        backend: str = "ocp_qp",
        hpipm_mode: str = "balance",
    ) -> None:
        """``specialise``: a library compiled for exactly these nx, nu, nc, ncN (one more build, cached);
        ``source``: another ocp_qp.c text (see :func:`library`); ``backend``: one of :data:`BACKENDS`
        ('hpipm': OcpQPError naming the cause when HPIPM cannot be built or loaded; ``specialise`` and
        ``source`` are then ignored); ``hpipm_mode``: 'speed', 'balance' or 'robust'."""
        if not isinstance(dims, OcpQPDims):
            raise ParameterError(f"dims must be an OcpQPDims, got {type(dims).__name__}")
        settings = settings or OcpQPSettings()
        if not isinstance(settings, OcpQPSettings):
            raise ParameterError(f"settings must be an OcpQPSettings or None, got {type(settings).__name__}")
        if backend not in BACKENDS:
            raise ParameterError(f"backend = {backend!r} is not allowed: must be one of {BACKENDS}")
        if hpipm_mode not in HPIPM_MODES:
            raise ParameterError(f"hpipm_mode = {hpipm_mode!r} is not allowed: must be one of {tuple(HPIPM_MODES)}")
        self.dims, self.settings, self.backend = dims, settings, backend
        cd = _Dims(dims.N, dims.nx, dims.nu, dims.nc, dims.ncN)
        cs = _Settings(
            settings.max_iter,
            settings.tol_stat,
            settings.tol_eq,
            settings.tol_ineq,
            settings.tol_comp,
            settings.reg_prim,
        )
        if backend == "hpipm":
            lib = hpipm_library()
            if isinstance(lib, str):
                raise OcpQPError(f"the HPIPM backend is unavailable: {lib}")
            if lib.ocpqp_hpipm_unsupported(ctypes.byref(cd)):
                raise OcpQPError(
                    f"the HPIPM backend refuses nx = 1 with nx + nu a multiple of 4 ({dims}): the "
                    "shipped libhpipm returns wrong controls there (aev_ocp/c/ocp_qp_hpipm.c)"
                )
            self._lib = lib
            self._ptr = lib.ocpqp_hpipm_create(ctypes.byref(cd), ctypes.byref(cs), HPIPM_MODES[hpipm_mode])
        else:
            self._lib = library((dims.nx, dims.nu, dims.nc, dims.ncN) if specialise else None, source)
            self._ptr = self._lib.ocpqp_create(ctypes.byref(cd), ctypes.byref(cs))
        if not self._ptr:
            raise OcpQPError(f"ocpqp_create failed for {dims} (out of memory?)")
        self._data = _Data()
        self._info = _Info()
        self._keep: dict[str, np.ndarray] = {}

    def __del__(self) -> None:
        ptr, lib = getattr(self, "_ptr", None), getattr(self, "_lib", None)
        if ptr and lib is not None:
            lib.ocpqp_free(ptr)
            self._ptr = None

    def _shapes(self) -> dict[str, list[tuple[int, int]]]:
        return _block_shapes(self.dims)

    def set_data(self, H: Any, g: Any, E: Any, e: Any, C: Any, lc: Any, uc: Any, lbw: Any, ubw: Any, x0: Any) -> None:
        """Check and store the QP data (each a flat column-major array or a sequence of stage blocks;
        C, lc, uc may be None when nc = ncN = 0)."""
        shapes = self._shapes()
        given = dict(H=H, g=g, E=E, e=e, C=C, lc=lc, uc=uc, lbw=lbw, ubw=ubw, x0=x0)
        for name in _DATA_FIELDS:
            v = given[name]
            if v is None and name in ("C", "lc", "uc") and self.dims.nc + self.dims.ncN == 0:
                v = np.zeros(0)
            if v is None:
                raise ParameterError(f"{name} is required")
            if name == "x0":
                arr = np.ascontiguousarray(v, dtype=float).reshape(-1)
                if arr.size != self.dims.nx:
                    raise ParameterError(f"x0 must have nx = {self.dims.nx} entries, got {arr.size}")
            else:
                arr = _pack(name, v, shapes[name])
            self._keep[name] = arr
            setattr(self._data, name, arr.ctypes.data if arr.size else None)

    def _guess(self, name: str, v: Any, n: int) -> np.ndarray | None:
        """One part of a warm-start guess: None, or a flat float array of n entries (ParameterError naming it)."""
        if v is None:
            return None
        arr = np.ascontiguousarray(v, dtype=float).reshape(-1)
        if arr.size != n:
            raise ParameterError(f"the warm-start guess {name} must have {n} entries, got {arr.size}")
        return arr

    def solve_data(self, warm: dict[str, Any] | None = None) -> OcpQPResult:
        """Solve the QP last given to :meth:`set_data`; ``warm``: a primal-dual guess to start from
        (ocpqp_solve_warm: keys w, pi, lam_w, lam_c, each optional, laid out as the result's; None: the cold
        start; the HPIPM backend ignores it)."""
        if len(self._keep) != len(_DATA_FIELDS):
            raise ParameterError("solve_data called before set_data")
        d = self.dims
        w, pi = np.zeros(d.nw), np.zeros(d.N * d.nx)
        lam_w, lam_c = np.zeros(d.nw), np.zeros(d.N * d.nc + d.ncN)
        outs = (
            w.ctypes.data,
            pi.ctypes.data,
            lam_w.ctypes.data,
            lam_c.ctypes.data if lam_c.size else None,
            ctypes.byref(self._info),
        )
        if warm is None:
            st = self._lib.ocpqp_solve(self._ptr, ctypes.byref(self._data), *outs)
        else:
            unknown = set(warm) - {"w", "pi", "lam_w", "lam_c"}
            if unknown:
                raise ParameterError(f"unknown warm-start keys {sorted(unknown)}: allowed w, pi, lam_w, lam_c")
            sizes = {"w": d.nw, "pi": d.N * d.nx, "lam_w": d.nw, "lam_c": d.N * d.nc + d.ncN}
            g = [self._guess(k, warm.get(k), n) for k, n in sizes.items()]
            ptrs = [a.ctypes.data if a is not None and a.size else None for a in g]
            st = self._lib.ocpqp_solve_warm(self._ptr, ctypes.byref(self._data), *ptrs, *outs)
        i = self._info
        return OcpQPResult(
            w,
            pi,
            lam_w,
            lam_c,
            int(st),
            int(i.iterations),
            {"stat": i.res_stat, "eq": i.res_eq, "ineq": i.res_ineq, "comp": i.res_comp},
        )

    def solve(
        self,
        H: Any,
        g: Any,
        E: Any,
        e: Any,
        C: Any,
        lc: Any,
        uc: Any,
        lbw: Any,
        ubw: Any,
        x0: Any,
        warm: dict[str, Any] | None = None,
    ) -> OcpQPResult:
        """Check the data (ParameterError naming a wrongly sized argument) and solve, from the guess ``warm``
        if given (see :meth:`solve_data`); a failed solve is a status in the result, not an exception."""
        self.set_data(H, g, E, e, C, lc, uc, lbw, ubw, x0)
        return self.solve_data(warm)

    def timed_calls(self, n: int) -> np.ndarray:
        """Wall time in seconds of ``n`` repeated C solves of the data last set (for benchmarks: the
        outputs go to preallocated buffers, so this is the C solve plus one ctypes call)."""
        import time

        d = self.dims
        w, pi = np.zeros(d.nw), np.zeros(d.N * d.nx)
        lam_w, lam_c = np.zeros(d.nw), np.zeros(max(1, d.N * d.nc + d.ncN))
        args = (
            self._ptr,
            ctypes.byref(self._data),
            w.ctypes.data,
            pi.ctypes.data,
            lam_w.ctypes.data,
            lam_c.ctypes.data,
            ctypes.byref(self._info),
        )
        f = self._lib.ocpqp_solve
        out = np.empty(n)
        clock = time.perf_counter
        for j in range(n):
            t0 = clock()
            f(*args)
            out[j] = clock() - t0
        return out


# ---------------------------------------------------------------------------------------------- test data
def random_qp(
    dims: OcpQPDims, rng: np.random.Generator, equality_rows: float = 0.3, absent: float = 0.25, scale: float = 3.0
) -> dict[str, Any]:
    """A random convex OCP QP, feasible by construction (for tests and benchmarks): a trajectory w* is
    drawn first and every bound and general row is put around it (a side absent (+-inf) with probability ``absent``; with probability ``equality_rows`` the
    first general row of a stage an equality lc = uc = C w*). H_k = M M' plus a
    positive control diagonal (PSD, PD control block). Values are of order ``scale``. Returns the data
    as stage blocks, keyed like :meth:`OcpQP.solve`'s arguments."""
    N, nx, nu, nb, nc, ncN = dims.N, dims.nx, dims.nu, dims.nb, dims.nc, dims.ncN
    H, g, E, e, C, lc, uc, lbw, ubw = [], [], [], [], [], [], [], [], []
    x = rng.normal(scale=scale, size=nx)
    x0 = x.copy()

    def box(v: np.ndarray, p_absent: float) -> tuple[np.ndarray, np.ndarray]:
        lo = v - rng.uniform(0.05, 1.5, v.size) * scale
        up = v + rng.uniform(0.05, 1.5, v.size) * scale
        lo[rng.random(v.size) < p_absent] = -np.inf
        up[rng.random(v.size) < p_absent] = np.inf
        return lo, up

    for k in range(N + 1):
        n, m = (nb, nc) if k < N else (nx, ncN)
        u = rng.normal(scale=scale, size=n - nx)
        wk = np.concatenate([x, u])
        M = rng.normal(size=(n, max(1, n // 2)))
        Hk = M @ M.T
        Hk[nx:, nx:] += np.diag(rng.uniform(0.3, 2.0, n - nx))
        H.append(Hk)
        g.append(rng.normal(scale=scale, size=n))
        lo, up = box(wk, absent)
        lbw.append(lo)
        ubw.append(up)
        Ck = rng.normal(size=(m, n))
        cw = Ck @ wk
        clo, cup = box(cw, absent)
        if m > 0 and rng.random() < equality_rows:
            clo[0] = cup[0] = cw[0]
        C.append(Ck)
        lc.append(clo)
        uc.append(cup)
        if k < N:
            A = rng.normal(size=(nx, nx))
            A = 0.9 * A / max(1e-9, float(np.max(np.abs(np.linalg.eigvals(A)))))
            Ek = np.hstack([A, rng.normal(size=(nx, nu))])
            ek = rng.normal(scale=0.3 * scale, size=nx)
            E.append(Ek)
            e.append(ek)
            x = Ek @ wk + ek
    return dict(H=H, g=g, E=E, e=e, C=C, lc=lc, uc=uc, lbw=lbw, ubw=ubw, x0=x0)


def _casadi_bounds(v: np.ndarray) -> np.ndarray:
    """Bounds with |value| >= INF as +-inf (CasADi's absent bound)."""
    return np.where(np.abs(v) >= INF, np.copysign(np.inf, v), v)


def sparse_qp(dims: OcpQPDims, data: dict[str, Any]) -> dict[str, Any]:
    """The same QP in CasADi's full-space form for ``ca.conic`` (variables the stacked w; constraint rows
    stage by stage the dynamics E_k w_k - x_{k+1} = -e_k then the stage's general rows, as HPIPM's
    interface wants them; x_0 fixed by its bounds): a dict with the sparse 'h' and 'a' (casadi DM), the
    vectors g, lba, uba, lbx, ubx and the row indices rows_pi (dynamics, multipliers pi) and rows_c
    (general rows, multipliers lam_c); lam_x are lam_w."""
    import casadi as ca

    N, nx, nb, nc, ncN, nw = dims.N, dims.nx, dims.nb, dims.nc, dims.ncN, dims.nw
    sh = _block_shapes(dims)
    blocks = {
        k: _pack(k, data[k], sh[k]) if not (k in ("C", "lc", "uc") and data.get(k) is None) else np.zeros(0)
        for k in _DATA_FIELDS
        if k != "x0"
    }
    Hf = np.zeros((nw, nw))
    nrow = N * (nx + nc) + ncN
    Af = np.zeros((nrow, nw))
    rows_pi = np.concatenate([np.arange(nx) + k * (nx + nc) for k in range(N)])
    rows_c = np.setdiff1d(np.arange(nrow), rows_pi)
    lba, uba = np.zeros(nrow), np.zeros(nrow)
    pos_h = pos_e = pos_c = 0
    for k in range(N + 1):
        n, m = (nb, nc) if k < N else (nx, ncN)
        o, r = k * nb, k * (nx + nc)
        Hf[o : o + n, o : o + n] = blocks["H"][pos_h : pos_h + n * n].reshape((n, n), order="F")
        pos_h += n * n
        rc = r + nx if k < N else r
        Af[rc : rc + m, o : o + n] = blocks["C"][pos_c : pos_c + m * n].reshape((m, n), order="F")
        pos_c += m * n
        if k < N:
            Af[r : r + nx, o : o + nb] = blocks["E"][pos_e : pos_e + nx * nb].reshape((nx, nb), order="F")
            Af[r : r + nx, o + nb : o + nb + nx] = -np.eye(nx)
            pos_e += nx * nb
    lba[rows_pi] = uba[rows_pi] = -blocks["e"]
    lba[rows_c], uba[rows_c] = _casadi_bounds(blocks["lc"]), _casadi_bounds(blocks["uc"])
    lbx, ubx = _casadi_bounds(blocks["lbw"]), _casadi_bounds(blocks["ubw"])
    x0 = np.asarray(data["x0"], dtype=float).reshape(-1)
    lbx[:nx] = ubx[:nx] = x0
    return dict(
        h=ca.sparsify(ca.DM(Hf)),
        a=ca.sparsify(ca.DM(Af)),
        g=blocks["g"],
        lba=lba,
        uba=uba,
        lbx=lbx,
        ubx=ubx,
        rows_pi=rows_pi,
        rows_c=rows_c,
    )
