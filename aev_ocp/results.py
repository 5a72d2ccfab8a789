"""One result type for every controller (closed-form law, MPC, offline optimum) and atomic writers.

A :class:`SimulationResult` holds sampled trajectories of a platoon (model units unless the name
says otherwise) and the *cumulative* integrals that the metrics of model guide §10 need, integrated
by the plant's own quadrature (exact across control jumps, unlike a trapezoid on samples).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import tempfile
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar, Iterator

import numpy as np

from .errors import AevOcpError
from . import interrupts
from .limits import _os_reason, read_input_file
from .params import EVParams, Units, as_dict, echo

_UMASK = os.umask(0)
os.umask(_UMASK)

EVENT_KINDS = (
    "collision",
    "negative_speed",
    "infeasible_current",
    "soc_out_of_range",
    "integration_failed",
    "time_limit",
    "estimation_failed",
)  # estimation_failed: an estimator returned a NaN/inf state (the run stopped there); time_limit: the run was stopped by its wall-clock limit (vehicle -1: the whole run)
VIOLATED = "violated"  # status of a run that went below a controller's own hard gap floor (it did not stop)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a unique temporary path beside ``path``; on success it replaces ``path`` atomically.

    The temporary file is created by mkstemp (a unique name, so concurrent writers into one folder
    never collide), given the mode a plain ``open()`` would give (0666 & ~umask, not mkstemp's 0600),
    and removed on any failure, Ctrl-C included.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp: Path | None = None
    try:
        with interrupts.deferred():  # a Ctrl-C right after mkstemp created the file must not leak it
            fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
            os.close(fd)
            tmp = Path(tmp_name)
        os.chmod(tmp, 0o666 & ~_UMASK)
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp is not None:
            with interrupts.deferred():
                try:
                    tmp.unlink()
                except FileNotFoundError:
                    pass


def write_atomic(path: str | os.PathLike[str], data: str | bytes) -> Path:
    """Write ``data`` to ``path`` atomically (unique temp file in the same folder, then os.replace)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(
            tmp, "wb" if isinstance(data, bytes) else "w", encoding=None if isinstance(data, bytes) else "utf-8"
        ) as fh:
            fh.write(data)
    return path


def save_figure_atomic(fig: Any, path: str | os.PathLike[str], **savefig_kwargs: Any) -> Path:
    """Save a matplotlib figure as ``path`` atomically (see :func:`atomic_path`); the figure stays open.

    A figure laid out once by ``fig.tight_layout()`` is drawn once, not twice: tight_layout leaves a placeholder
    layout engine on the figure (it lays out nothing), and matplotlib's savefig draws a figure with any layout engine
    once without rendering before it renders it (for layouts computed at draw time, such as constrained layout). The
    placeholder is taken off for the save and put back: the file is the same byte for byte, about half of a
    figure's save time less (issue 40). A figure with a working layout engine (constrained) is saved as it is."""
    from matplotlib.layout_engine import PlaceHolderLayoutEngine

    path = Path(path)
    fmt = savefig_kwargs.pop("format", path.suffix.lstrip(".") or "png")
    engine = getattr(fig, "get_layout_engine", lambda: None)()  # anything with a savefig method is accepted
    placeholder = isinstance(engine, PlaceHolderLayoutEngine)
    with atomic_path(path) as tmp:
        if placeholder:
            _set_no_layout_engine(fig)
        try:
            fig.savefig(tmp, format=fmt, **savefig_kwargs)
        finally:
            if placeholder:
                fig.set_layout_engine(engine)
    return path


def _set_no_layout_engine(fig: Any) -> None:
    """``fig`` without a layout engine (matplotlib's set_layout_engine(None) picks the rc's default engine instead
    when ``figure.autolayout`` or ``figure.constrained_layout.use`` is set: both off for this call)."""
    import matplotlib as mpl

    with mpl.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
        fig.set_layout_engine(None)


# ----------------------------------------------------------------------------- notebook display
PANDAS_HINT = "pip install 'aev_ocp[pandas]'  (or: pip install pandas)"


def require_pandas(what: str) -> Any:
    """The pandas module, or ImportError with the one line that installs it (pandas is an optional extra)."""
    try:
        import pandas
    except ImportError:
        raise ImportError(f"{what} needs pandas, which is not installed; install it with: {PANDAS_HINT}") from None
    return pandas


def fmt_value(x: Any) -> str:
    """A short text of a number (4 significant digits) or of anything else (its str, cut at 60 characters)."""
    if isinstance(x, bool) or x is None:
        return str(x)
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        return f"{float(x):.4g}"
    text = str(x)
    return text if len(text) <= 60 else text[:57] + "..."


def summary_text(title: str, lines: list[str]) -> str:
    """A short ``repr``: the title, then each line indented by two spaces."""
    return "\n".join([title, *("  " + ln for ln in lines)])


def summary_html(title: str, fields: list[tuple[str, Any]], rows: list[dict[str, Any]] | None = None) -> str:
    """A short HTML ``_repr_html_``: the title, a two-column table of ``fields`` and an optional table of ``rows``
    (at most 20 shown), every value escaped."""
    from html import escape

    parts = [f"<div><strong>{escape(title)}</strong>", "<table>"]
    parts += [
        f"<tr><th style='text-align:left'>{escape(k)}</th><td style='text-align:left'>{escape(fmt_value(v))}</td></tr>"
        for k, v in fields
    ]
    parts.append("</table>")
    if rows:
        cols = list(rows[0])
        parts.append("<table><tr>" + "".join(f"<th>{escape(c)}</th>" for c in cols) + "</tr>")
        parts += [
            "<tr>" + "".join(f"<td>{escape(fmt_value(r.get(c)))}</td>" for c in cols) + "</tr>" for r in rows[:20]
        ]
        parts.append("</table>")
        if len(rows) > 20:
            parts.append(f"<p>… {len(rows) - 20} more rows</p>")
    parts.append("</div>")
    return "\n".join(parts)


# ----------------------------------------------------------------------------- output folders
_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._+-]{0,99}")
MARKER = "aev-ocp-run.json"  # which command and scenario wrote this folder


class OutputError(AevOcpError, ValueError):
    """An output folder cannot be used (it holds another run's files); the message says which and why."""


class FieldsRepr:
    """``__repr__`` and ``_repr_html_`` of a result that states itself as ``_repr_fields() -> (title, [(name,
    value), ...])``: the title, then one ``name: value`` line (text) or table row (HTML) per field."""

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]]]:
        raise NotImplementedError

    def __repr__(self) -> str:
        title, fields = self._repr_fields()
        return summary_text(title, [f"{k}: {fmt_value(v)}" for k, v in fields])

    def _repr_html_(self) -> str:
        title, fields = self._repr_fields()
        return summary_html(title, fields)


def check_safe_name(name: str, what: str = "name") -> str:
    """``name`` if it is a safe single folder name (1-100 of A-Z a-z 0-9 . _ + -, not starting with
    '.', '_', '+' or '-'), else ValueError: a name must never lead outside the output folder."""
    if not isinstance(name, str) or not _SAFE_NAME.fullmatch(name) or name in (".", ".."):
        raise ValueError(
            f"{what} = {echo(name)} is not allowed: must be 1-100 characters of letters, digits, "
            "'.', '_', '+', '-', starting with a letter or digit (it names a folder under results/)"
        )
    return name


def default_output_dir(*parts: str, root: str | os.PathLike[str] = "results") -> Path:
    """``root/parts…`` where every part is checked with :func:`check_safe_name` (no absolute paths, no '..')."""
    for part in parts:
        check_safe_name(part)
    return Path(root).joinpath(*parts)


def claim_output_dir(
    out: str | os.PathLike[str],
    command: str,
    scenario: str,
    source: str | None,
    files: Iterator[str] | list[str] | tuple[str, ...] | None = None,
) -> Path:
    """Make ``out`` ready for the files of one run, never clobbering another run's files silently.

    The folder gets a marker naming the command, the scenario and its source file. If it already holds
    a marker of a *different* command/scenario/source, or (without a marker) any of ``files`` (names or glob
    patterns such as ``space_time_*.png``; None: the run's files are not listed, so any entry at all), an
    :class:`OutputError` says so: re-running the same scenario into its own folder replaces its files.
    """
    out = Path(out)
    try:
        if out.exists() and not out.is_dir():
            raise OutputError(f"output folder {out} exists and is not a folder")
        if out.is_symlink() and not out.exists():
            raise OutputError(f"output folder {out} is a symbolic link to {os.readlink(out)!r}, which does not exist")
        me = {"command": command, "scenario": scenario, "source": str(Path(source).resolve()) if source else None}
        files = None if files is None else list(files)
        _check_claim(out, me, files)  # before anything is written: a refused folder stays as it was
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a name too long, a dangling symbolic link, no permission: say which folder, shortly
        shown = str(out) if len(str(out)) <= 120 else f"{str(out)[:60]}…{str(out)[-40:]} ({len(str(out))} characters)"
        raise OutputError(f"output folder {shown} cannot be created or read ({_os_reason(exc)})") from None
    _acquire_lock(out)  # held until the command ends (release_output_locks): a second run is refused at once
    _check_claim(out, me, files)  # again under the lock: a run that started meanwhile has written its marker
    if (out / MARKER).is_file():  # the same command and scenario ran here before: its outputs are replaced whole
        _remove_previous_outputs(out)
    write_json(out / MARKER, me, provenance=False)
    return out


#: What an earlier run of the same command into its own folder leaves that the new run replaces: its figures,
#: tables, reports and saved runs at the folder's top level (a figure of a law or case the new run no longer has
#: would otherwise stay beside the new ones, looking current).
STALE_SUFFIXES = (".png", ".svg", ".pdf", ".csv", ".md", ".html", ".json", ".npz")


def _remove_previous_outputs(out: Path) -> None:
    """Remove the top-level output files (:data:`STALE_SUFFIXES`) of the earlier run of the same command in
    ``out`` (its marker matched; called under the folder's lock); the marker itself is rewritten after."""
    for p in out.iterdir():
        if p.name != MARKER and p.suffix in STALE_SUFFIXES and p.is_file() and not p.is_symlink():
            try:
                p.unlink()
            except OSError:
                pass


def _check_claim(out: Path, me: dict[str, Any], files: list[str] | None) -> None:
    """OutputError if ``out`` holds another run's marker or (without a marker) files it did not write."""
    marker = out / MARKER
    if (marker.exists() or marker.is_symlink()) and not marker.is_file():  # a FIFO, folder, device: not ours
        raise OutputError(
            f"output folder {out} holds {MARKER}, which is not a file aev-ocp wrote (a folder, FIFO, "
            "device or dangling link); choose another --out, or remove it first"
        )
    if marker.is_file():
        try:  # a marker is ~100 bytes of JSON; a huge or deeply nested one is not ours
            prev = json.loads(read_input_file(marker, "marker", OutputError, 1_000_000).decode("utf-8"))
        except (OSError, ValueError, RecursionError):
            prev = None
        if not isinstance(prev, dict) or {k: prev.get(k) for k in me} != me:
            who = (
                f"'aev-ocp {prev.get('command')}' of scenario {prev.get('scenario')!r}"
                + (f" ({prev['source']})" if prev.get("source") else "")  # a ring experiment has no file
                if isinstance(prev, dict)
                else "an unreadable marker"
            )
            raise OutputError(
                f"output folder {out} holds the results of {who}; choose another --out, or "
                f"remove {out} first (files of other runs are never replaced)"
            )
    elif out.is_dir():
        clash = sorted(
            {p.name for p in out.iterdir() if p.name != LOCK}
            if files is None
            else {p.name for pattern in files for p in out.glob(pattern)}
        )
        if clash:
            raise OutputError(
                f"output folder {out} already holds {clash[0]}"
                f"{f' and {len(clash) - 1} more' if len(clash) > 1 else ''}"
                f"{' of the files this run writes' if files is not None else ''}, "
                "not written by aev-ocp; choose another --out, or remove them first"
            )


LOCK = ".aev-ocp.lock"  # held (flock) by the one run writing into a folder


_HELD_LOCKS: dict[str, int] = {}  # resolved folder -> descriptor of the lock this process holds on it


def _acquire_lock(out: Path) -> str | None:
    """Lock folder ``out`` (it exists) for this process: its key, or None if this process holds it already;
    OutputError at once if another process holds it."""
    import fcntl

    key = str(out.resolve())
    held = _HELD_LOCKS.get(key)
    if held is not None:
        if _is_lock_of(held, out):
            return None
        # the folder (or its lock file) was removed and made again since: the old lock guards nothing, take a new
        # one for its holder (its key stays the same, so whoever took the old one releases the new one)
        del _HELD_LOCKS[key]
        os.close(held)
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o666 & ~_UMASK)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
    except BlockingIOError:
        os.close(fd)
        raise OutputError(
            f"output folder {out} is in use by another aev-ocp run (pid in {out / LOCK}); wait for "
            "it to finish or choose another --out"
        ) from None
    except BaseException:
        os.close(fd)
        raise
    _HELD_LOCKS[key] = fd
    return None if held is not None else key


def _is_lock_of(fd: int, out: Path) -> bool:
    """Whether descriptor ``fd`` is still the lock file of folder ``out`` (same device and inode)."""
    try:
        a, b = os.fstat(fd), os.stat(out / LOCK, follow_symlinks=False)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def release_output_locks(key: str | None = None) -> None:
    """Release the folder lock ``key`` (from :func:`_acquire_lock`), or every lock this process holds (None:
    the end of a command, :func:`aev_ocp.console.guarded`)."""
    for k in [key] if key is not None else list(_HELD_LOCKS):
        fd = _HELD_LOCKS.pop(k, None)
        if fd is not None:
            try:  # the pid inside names the holder only while it runs: a finished run leaves no pid behind
                os.ftruncate(fd, 0)
            except OSError:
                pass
            os.close(fd)


@contextlib.contextmanager
def output_lock(out: str | os.PathLike[str]) -> Iterator[Path]:
    """Hold an exclusive lock on the folder ``out`` (created if needed) for the block: a second run into the
    same folder gets an :class:`OutputError` at once instead of mixing its files with the first one's.
    The lock is an flock on ``out/.aev-ocp.lock``: the system releases it when the process ends, however.
    (:func:`claim_output_dir` takes the same lock; inside this block it is already held.)"""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    key = _acquire_lock(out)
    try:
        yield out
    finally:
        if key is not None:  # a lock this block took (not one its caller holds)
            release_output_locks(key)


def to_jsonable(x: Any) -> Any:
    """numpy arrays/scalars -> lists/floats, non-finite floats -> None, dataclasses -> dicts, recursively."""
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.floating, float)):
        xf = float(x)
        return xf if math.isfinite(xf) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if hasattr(x, "__dataclass_fields__"):
        return to_jsonable(as_dict(x))
    return x


def write_json(path: str | os.PathLike[str], obj: Any, provenance: bool = True) -> Path:
    """Atomically write ``obj`` as indented JSON (numpy values converted, non-finite -> null). A dict gets
    a ``provenance`` record (:func:`aev_ocp.provenance.provenance`) unless it has one or ``provenance``
    is False."""
    if provenance and isinstance(obj, dict) and "provenance" not in obj:
        from .provenance import provenance as _record

        obj = {**obj, "provenance": _record()}
    return write_atomic(path, json.dumps(to_jsonable(obj), indent=2) + "\n")


@dataclass
class Event:
    """Something the simulation must not integrate through: kind, time [model], vehicle (0-based follower
    index; -1 for the whole run, e.g. a time limit). time_s: the same time [s] where the plant knew the units;
    impact_speed_mps: for a collision, the closing speed v − v_l at contact [m/s]. A floor violation (kind
    'violated', :attr:`SimulationResult.violations`) is reported the same way but did not stop the run."""

    kind: str
    time: float
    vehicle: int
    message: str
    time_s: float | None = None
    impact_speed_mps: float | None = None

    def __str__(self) -> str:
        who = f"vehicle {self.vehicle + 1}" if self.vehicle >= 0 else "whole run"
        if self.time_s is not None and math.isfinite(self.time_s):  # SI first, the model time in parentheses
            return f"{self.kind} at t = {self.time_s:.4g} s ({self.time:.6g} model), {who}: {self.message}"
        return f"{self.kind} at t = {self.time:.4f} ({who}): {self.message}"


@dataclass
class SimulationResult:
    """Sampled platoon trajectories. Arrays are (K,) or (K, n) with n followers; model units unless named.

    cumulative integrals (K, n): omega (the paper's ω, model units: the paper's measure, not battery energy),
    heat_J and heat_irr_J (pack ∫Q, ∫Q_irr [J]), battery_energy_J (∫P_b [J], when the plant integrated it), int_ovm_err2 = ∫(V(h) − v)² dt, int_rel_speed2 = ∫(v_l − v)² dt, int_jerk2 = ∫ jerk² dt.
    """

    t: np.ndarray
    leader_speed: np.ndarray
    leader_position: np.ndarray
    gap: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    V1: np.ndarray
    V2: np.ndarray
    S: np.ndarray
    current_A: np.ndarray
    omega: np.ndarray
    heat_J: np.ndarray
    heat_irr_J: np.ndarray
    int_ovm_err2: np.ndarray
    int_rel_speed2: np.ndarray
    int_jerk2: np.ndarray
    controllers: list[str]
    ev: EVParams = field(default_factory=EVParams)
    events: list[Event] = field(default_factory=list)
    jerk_sampled: bool = False
    solver_stats: list[dict[str, Any] | None] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    violations: list[Event] = field(default_factory=list)
    temperature_K: np.ndarray | None = None  # (K, n) pack temperature [K] when the thermal model is on, else None
    battery_energy_J: np.ndarray | None = None  # (K, n) cumulative battery energy ∫P_b dt [J] when the plant
    # integrated it (SUMO, replay-like plants); None: aev_ocp.metrics evaluates it on the samples

    @property
    def status(self) -> str:
        """The kind of the first event (the run stopped there), else 'violated' when a vehicle went below its
        controller's own hard gap floor (:attr:`violations`, the run went on), else 'ok'."""
        return self.events[0].kind if self.events else ("violated" if self.violations else "ok")

    @property
    def n_vehicles(self) -> int:
        """Number of followers."""
        return int(self.gap.shape[1])

    @property
    def units(self) -> Units:
        """The scenario's units."""
        return self.ev.units

    def positions(self) -> np.ndarray:
        """Follower positions x_n(t) [model length], leader at x_l(0) = 0."""
        return self.leader_position[:, None] - np.cumsum(self.gap, axis=1)

    def metrics(self) -> list[dict[str, Any]]:
        """Per-vehicle metrics of model guide §10 (see :mod:`aev_ocp.metrics`)."""
        from .metrics import vehicle_metrics

        return [vehicle_metrics(self, i) for i in range(self.n_vehicles)]

    #: Trajectory CSV columns: (header, attribute, SI factor name or None). SI first, units in the names;
    #: the model-unit columns follow with a ``_model`` suffix (the car-following model's own units).
    CSV_COLUMNS: ClassVar[tuple[tuple[str, str, str | None], ...]] = (
        ("gap_m", "gap", "length_m"),
        ("speed_mps", "speed", "speed_mps"),
        ("accel_mps2", "accel", "accel_mps2"),
        ("V1_V", "V1", None),
        ("V2_V", "V2", None),
        ("soc", "S", None),
        ("current_A", "current_A", None),
        ("omega_J_per_kg", "omega", "omega"),
        ("heat_J", "heat_J", None),
        ("heat_irr_J", "heat_irr_J", None),
        ("gap_model", "gap", None),
        ("speed_model", "speed", None),
        ("accel_model", "accel", None),
        ("omega_model", "omega", None),
    )

    def plot(self, si: bool = True, title: str | None = None) -> Any:
        """Gaps, speeds (with the leader's), accelerations, cell current [A], SOC and pack heat against time
        (:func:`aev_ocp.plots.plot_trajectories`; axes in s, m, km/h, ``si=False``: model units): a matplotlib
        Figure. The figure module is imported here, when called (a late edge of the layer table)."""
        from .plots import plot_trajectories

        return plot_trajectories(self, None, title=title, si=si)

    def to_csv(self, path: str | os.PathLike[str]) -> Path:
        """Long-format CSV (one row per time and vehicle), streamed to a temp file and moved into place
        atomically. Columns: t_s, vehicle, controller, leader_speed_mps, then :attr:`CSV_COLUMNS` (SI first,
        named with their units; battery states V1_V, V2_V [V], soc [-], current_A [A per cell], heat_J [J];
        omega_J_per_kg [J/kg]), then t_model, leader_speed_model and the other ``_model`` columns. Memory stays
        O(samples of one vehicle) whatever the platoon size; each vehicle's rows are formatted by one ``%``
        operation."""
        u = self.units
        scale = {
            "length_m": u.length_m,
            "speed_mps": u.speed_mps,
            "accel_mps2": u.accel_mps2,
            "omega": u.speed_mps**2,
        }  # ω [U²] -> J/kg (Units.energy_per_mass_to_si)
        cols = self.CSV_COLUMNS
        if self.temperature_K is not None:  # the pack temperature [K] after the heat columns
            k = [c[0] for c in cols].index("heat_irr_J") + 1
            cols = cols[:k] + (("temperature_K", "temperature_K", None),) + cols[k:]
        T = u.time_s
        t_txt = [f"{t:.6g}" for t in self.t]
        ts_txt = [f"{t * T:.6g}" for t in self.t]
        vl_si = [f"{v * u.speed_mps:.10g}" for v in self.leader_speed]
        vl_txt = [f"{v:.10g}" for v in self.leader_speed]
        n_si = sum(1 for c in cols if not c[0].endswith("_model"))
        row = "%s,%d,%s,%s," + ",".join(["%.10g"] * n_si) + ",%s,%s," + ",".join(["%.10g"] * (len(cols) - n_si)) + "\n"
        K = self.t.size
        with atomic_path(path) as tmp:
            with open(tmp, "w", newline="", encoding="utf-8") as fh:
                fh.write(
                    ",".join(
                        ["t_s", "vehicle", "controller", "leader_speed_mps"]
                        + [c[0] for c in cols[:n_si]]
                        + ["t_model", "leader_speed_model"]
                        + [c[0] for c in cols[n_si:]]
                    )
                    + "\n"
                )
                for i in range(self.n_vehicles):
                    name = self.controllers[i]
                    if any(ch in name for ch in ',"\r\n'):  # needs CSV quoting
                        name = '"' + name.replace('"', '""') + '"'
                    arrs = [(getattr(self, a)[:, i] * (scale[f] if f else 1.0)).tolist() for _, a, f in cols]
                    flat = [
                        x
                        for r in zip(ts_txt, [i + 1] * K, [name] * K, vl_si, *arrs[:n_si], t_txt, vl_txt, *arrs[n_si:])
                        for x in r
                    ]
                    fh.write((row * K) % tuple(flat))
        return Path(path)

    #: how many vehicles a ``repr`` lists (the others are counted)
    REPR_VEHICLES: ClassVar[int] = 4

    def _repr_fields(self) -> tuple[str, list[tuple[str, Any]], list[dict[str, Any]]]:
        from .metrics import vehicle_metrics

        u = self.units
        names = sorted(set(self.controllers))
        title = (
            f"SimulationResult: {self.n_vehicles} follower{'s' if self.n_vehicles != 1 else ''} "
            f"({', '.join(names)}), status {self.status}"
        )
        t_s = float(u.time_to_si(self.t[-1])) if self.t.size else 0.0
        fields: list[tuple[str, Any]] = [("duration_s", t_s), ("samples", int(self.t.size))]
        if self.events:
            fields.append(("event", str(self.events[0])))
        if self.violations:
            fields.append(("floor violations", len(self.violations)))
        rows = []
        for i in range(min(self.n_vehicles, self.REPR_VEHICLES)):
            m = vehicle_metrics(self, i)
            rows.append(
                {
                    "vehicle": i + 1,
                    "controller": m["controller"],
                    "status": m["status"],
                    "omega_J_per_kg": m["omega_J_per_kg"],
                    "heat_pack_J": m["heat_pack_J"],
                    "min_gap_m": m["min_gap_m"],
                    "delta_soc": m["delta_soc"],
                }
            )
        return title, fields, rows

    def __repr__(self) -> str:
        """A few lines: who ran, the status, duration [s] and each vehicle's key metrics in SI."""
        title, fields, rows = self._repr_fields()
        lines = [", ".join(f"{k} {fmt_value(v)}" for k, v in fields)]
        lines += [
            f"vehicle {r['vehicle']} ({r['controller']}): {r['status']}, ω {fmt_value(r['omega_J_per_kg'])} J/kg, "
            f"pack ∫Q {fmt_value(r['heat_pack_J'])} J, min gap {fmt_value(r['min_gap_m'])} m, "
            f"ΔSOC {fmt_value(r['delta_soc'])}"
            for r in rows
        ]
        if self.n_vehicles > len(rows):
            lines.append(f"… {self.n_vehicles - len(rows)} more vehicles (.metrics() has them all)")
        return summary_text(title, lines)

    def _repr_html_(self) -> str:
        title, fields, rows = self._repr_fields()
        if self.n_vehicles > len(rows):
            fields.append(("vehicles not shown", self.n_vehicles - len(rows)))
        return summary_html(title, fields, rows)

    def to_dataframe(self) -> Any:
        """The trajectories as a long pandas DataFrame (one row per time and vehicle), with the columns of
        :meth:`to_csv`: t_s, vehicle, controller, leader_speed_mps, then SI columns (gap_m, speed_mps, …) and the
        model-unit ones (``_model``). Needs pandas (``pip install 'aev_ocp[pandas]'``)."""
        pd = require_pandas("SimulationResult.to_dataframe()")
        u = self.units
        scale = {"length_m": u.length_m, "speed_mps": u.speed_mps, "accel_mps2": u.accel_mps2, "omega": u.speed_mps**2}
        K, n = self.t.size, self.n_vehicles
        data: dict[str, Any] = {
            "t_s": np.tile(self.t * u.time_s, n),
            "vehicle": np.repeat(np.arange(1, n + 1), K),
            "controller": np.repeat(np.asarray(self.controllers, dtype=object), K),
            "leader_speed_mps": np.tile(self.leader_speed * u.speed_mps, n),
        }
        model_cols: dict[str, Any] = {
            "t_model": np.tile(self.t, n),
            "leader_speed_model": np.tile(self.leader_speed, n),
        }
        for name, attr, f in self.CSV_COLUMNS:
            col = (np.asarray(getattr(self, attr)) * (scale[f] if f else 1.0)).T.reshape(-1)
            (model_cols if name.endswith("_model") else data)[name] = col
        return pd.DataFrame({**data, **model_cols})

    def summary(self) -> dict[str, Any]:
        """Status, events, metrics and settings as a JSON-ready dict."""
        return {
            "status": self.status,
            "events": [vars(e) for e in self.events],
            "violations": [vars(e) for e in self.violations],
            "controllers": self.controllers,
            "metrics": self.metrics(),
            "units": as_dict(self.units),
            "meta": self.meta,
        }

    def to_json(self, path: str | os.PathLike[str]) -> Path:
        """Metrics and events as JSON, written atomically."""
        return write_json(path, self.summary())


#: The (K,) and (K, n) array fields of a :class:`SimulationResult`, in field order (``temperature_K``, an array
#: only with the thermal model, apart): what an output saves per run and a truncation cuts.
SIM_ARRAYS: tuple[str, ...] = tuple(f.name for f in fields(SimulationResult) if f.type == "np.ndarray")
