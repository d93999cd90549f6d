"""Fleets: calibrate or correct many logs, one output file per log and one summary table.

    report = nlpcal.calibrate_many("fleet/*.csv", "out", options={"method": "joint"},
                                   scheduler="local")

Each log is one task (`nlpcal.cluster.run_tasks`): it is read, calibrated and its parameters
written to `<name>.params.json` in the output folder (`apply_many`: corrected and written to
`<name>.corrected.csv`, or `.parquet` for a Parquet log), where <name> is the log's file name
without its suffix (with the folders under the logs' common folder, joined by "__", when logs in
different folders share a name). A log that cannot be read, calibrated or written becomes a row
of the summary with its status and the reason, and never stops the others. `summary.csv` in the
output folder has one row per log, in the order of the logs, written when the run ends (also when
it is interrupted, with the logs done so far).

A log whose output file is newer than the log (and than its parameters, for `apply_many`) and was
written with the same options (`nlpcal.batch.ledger`, `DIR/batch.json`) is not done again unless
`force`: its row is rebuilt from that output file. A log that fails loses the output an earlier
run wrote for it. On a cluster each worker process imports nlpcal once and builds each CasADi
problem once (`nlpcal.nlp.solver`), so the cost of a small log is its reading, its solves and its
writing.

Statuses and the exit status `nlpcal calibrate` or `nlpcal apply` would have given the log:

    ok 0, quality-failed 1 (the result fails a quality check; nothing written), solve-failed 1,
    bad-input 2 (the log or the options are unusable), error 1 (an output could not be written,
    the worker died, or a defect of nlpcal)

The summary of `calibrate_many` gives each log's verdict (`nlpcal.verdict`) beside its status: the
result's own ("ok", "warnings", "poorly_determined") when the status is ok, at least "warnings"
when the log was read with warnings, and "failed" for every other status.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from .. import cluster
from ..calibration import CalibrationResult
from ..correction import load_parameters
from ..errors import InputError
from ..io import Outputs
from ..io.files import COMPRESSED_SUFFIXES
from ..io.sources import distinct_files, is_parquet, log_paths
from ..io.strict import finite_table
from ..models.zhou2010 import PARAMETER_NAMES
from .ledger import FILE as LEDGER
from .ledger import Ledger, digest
from .tasks import (
    STATUSES,
    WARNING_SEPARATOR,
    ApplyTask,
    CalibrateTask,
    calibration_row,
    failure,
    status_row,
)

__all__ = [
    "APPLY_COLUMNS",
    "CALIBRATION_COLUMNS",
    "STATUSES",
    "WARNING_SEPARATOR",
    "BatchReport",
    "apply_many",
    "calibrate_many",
    "failure",
    "output_names",
]

SUMMARY = "summary.csv"
PARAMS_SUFFIX = ".params.json"
CORRECTED_TAG = ".corrected"
#: Columns of the summary of `calibrate_many`: the model that ran (full, diagonal or offset), the
#: nine parameters each followed by its standard error (_se, empty when the data leave a
#: direction free; both empty for a parameter the model does not estimate), the std of |B|
#: measured and corrected (the first and last Table 1 rows), the fraction of the 26 direction
#: bins the corrected field visits, and the unit with where it came from
#: (`nlpcal.units.UNIT_SOURCES`).
CALIBRATION_COLUMNS = (
    "log",
    "status",
    "verdict",
    "exit_status",
    "model",
    *[f"{name}{tail}" for name in PARAMETER_NAMES for tail in ("", "_se")],
    "std_measured",
    "std_corrected",
    "coverage_fraction",
    "warnings",
    "message",
    "unit",
    "unit_source",
    "n_samples",
    "output",
    "action",
    "seconds",
)
APPLY_COLUMNS = (
    "log",
    "status",
    "exit_status",
    "params",
    "output",
    "n_samples",
    "std_measured",
    "std_corrected",
    "outliers",
    "warnings",
    "message",
    "unit",
    "action",
    "seconds",
)
INTEGER_COLUMNS = {"exit_status", "n_samples", "outliers"}


@dataclass
class BatchReport:
    """What a batch did: one row per log, in the order of the logs, and where the summary went.

    Attributes
    ----------
    rows : list of dict
        One row per log, with the summary's columns (log, status, verdict, the nine parameters
        and their standard errors, ...).
    summary : pathlib.Path
        Where the summary table was written.
    columns : tuple of str
        The summary's columns.
    total : int
        Logs in the batch.
    notes : list of str
        What the batch decided on the user's behalf (logs named twice, outputs skipped).

    Examples
    --------
    >>> import os, tempfile
    >>> import nlpcal
    >>> folder = tempfile.mkdtemp()
    >>> nlpcal.simulate(300, seed=0).to_csv(os.path.join(folder, "a.csv"), index=False)
    >>> report = nlpcal.calibrate_many(os.path.join(folder, "a.csv"), os.path.join(folder, "out"))
    >>> report.rows[0]["status"], report.exit_status
    ('ok', 0)
    """

    rows: list
    summary: Path
    columns: tuple = CALIBRATION_COLUMNS
    total: int = 0
    notes: list = field(default_factory=list)

    def counts(self) -> dict:
        """How many logs ended in each status."""
        found: dict = {}
        for row in self.rows:
            found[row["status"]] = found.get(row["status"], 0) + 1
        return found

    @property
    def exit_status(self) -> int:
        """The largest exit status of a log (0 when every log is ok)."""
        return max((int(row["exit_status"]) for row in self.rows), default=0)

    def table(self) -> pd.DataFrame:
        """The summary: one row per log; counts as integers, empty where unknown."""
        frame = pd.DataFrame(self.rows, columns=list(self.columns))
        for name in INTEGER_COLUMNS & set(self.columns):
            frame[name] = frame[name].astype("Int64")
        return frame


def output_names(paths) -> dict:
    """A file name stem for each log, unique: the file name without its suffixes, with the
    folders under the common folder (joined by "__") when logs in different folders share a
    name, and the suffix kept when two logs differ by it alone."""
    paths = [Path(p) for p in paths]

    def stem(path: Path) -> str:
        name = path.name
        if path.suffix.lower() in COMPRESSED_SUFFIXES:
            name = name[: -len(path.suffix)]
        return name.rsplit(".", 1)[0] if "." in name.lstrip(".") else name

    names = {path: stem(path) for path in paths}
    if len(set(names.values())) < len(paths) and len({p.parent for p in paths}) > 1:
        root = Path(*_common_parts([p.resolve().parent.parts for p in paths]))
        names = {
            p: "__".join([*p.resolve().parent.relative_to(root).parts, stem(p)]) for p in paths
        }
    taken: dict = {}
    for path, name in names.items():
        taken.setdefault(name, []).append(path)
    for name, owners in taken.items():
        if len(owners) > 1:
            for path in owners:
                names[path] = name + "".join(path.suffixes).replace(".", "-")
    return names


def _common_parts(parts_list) -> tuple:
    common = parts_list[0]
    for parts in parts_list[1:]:
        k = 0
        while k < min(len(common), len(parts)) and common[k] == parts[k]:
            k += 1
        common = common[:k]
    return tuple(common)


def _out_dir(out_dir) -> Path:
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{out_dir}: cannot make the output folder ({exc.strerror})") from None
    return out_dir


def _run(
    jobs, task, reused, ledger: Ledger, keys: dict, columns, scheduler, workers, progress, notes
):
    """Run `task` on every job (log, ..., output) not in `reused` (log -> its row); write the
    summary and the ledger (`keys`: log -> the digest of what makes its output); `notes` go to
    the report."""
    rows = dict(reused)
    todo = [job for job in jobs if str(job[0]) not in rows]
    report = BatchReport([], ledger.path.parent / SUMMARY, columns, total=len(jobs))
    report.notes.extend(notes)
    if ledger.note:
        report.notes.append(ledger.note)
    ledger.redoing(job[-1] for job in todo)

    def finished(job, row):
        if isinstance(row, BaseException):
            row = status_row({"log": str(job[0]), "action": "run"}, *failure(row))
        rows[str(job[0])] = row
        if row["status"] == "ok":
            ledger.written(job[-1], keys[str(job[0])])
        else:
            ledger.failed(job[-1])
        if progress is not None:
            progress(len(rows), len(jobs), row)

    try:
        with cluster.scheduler(scheduler, workers) as client:
            cluster.run_tasks(task, todo, finished, client)
    finally:
        report.rows = [rows[str(job[0])] for job in jobs if str(job[0]) in rows]
        with Outputs() as outputs:  # the summary and the record of the outputs, together
            outputs.csv(report.summary, finite_table(report.table(), "the summary", missing=True))
            outputs.json(ledger.path, ledger.document())
    return report


def calibrate_many(
    source,
    out_dir,
    *,
    read_options: dict | None = None,
    options: dict | None = None,
    force: bool = False,
    scheduler=None,
    workers: int | None = None,
    progress=None,
) -> BatchReport:
    """Calibrate every log of `source` and write `<name>.params.json` per log and `summary.csv`.

    One bad log never stops the others; a log whose output is newer and was written with the same
    options is skipped unless `force`.

    Parameters
    ----------
    source : str, os.PathLike or sequence of them
        A glob pattern, a folder, a file or a list of files.
    out_dir : str or os.PathLike
        The output folder (`--out-dir`).
    read_options : dict, optional
        Keyword arguments of `read_log` (columns, unit, reference ...).
    options : dict, optional
        Keyword arguments of the calibration, as of `calibrate` (method, model, loss ...).
    force : bool
        Calibrate logs whose parameters file is newer than the log too (`--force`).
    scheduler : str or dask.distributed.Client, optional
        None (one log after another in this process), "threads", "processes", "local", the
        address of a running Dask scheduler, or a Client (`--scheduler`).
    workers : int, optional
        Workers of a local cluster (`--workers`).
    progress : callable, optional
        Called with (logs done, logs in all, the row of the latest) as each log finishes.

    Returns
    -------
    BatchReport
        One summary row per log, and where the summary was written.

    Raises
    ------
    InputError
        A source that names no log, or unusable options.

    Examples
    --------
    >>> import os, tempfile
    >>> import nlpcal
    >>> folder = tempfile.mkdtemp()
    >>> for k in range(2):
    ...     nlpcal.simulate(300, seed=k).to_csv(os.path.join(folder, f"log{k}.csv"), index=False)
    >>> report = nlpcal.calibrate_many(
    ...     os.path.join(folder, "*.csv"), os.path.join(folder, "out"), options={"method": "joint"}
    ... )
    >>> report.counts()
    {'ok': 2}
    """
    out_dir = _out_dir(out_dir)
    notes: list = []
    paths = _paths(source, out_dir, notes)
    names = output_names(paths)
    jobs = [(path, out_dir / f"{names[path]}{PARAMS_SUFFIX}") for path in paths]
    task = CalibrateTask(dict(read_options or {}), dict(options or {}))
    keys = {
        str(path): digest("calibrate", path, read_options=task.read_options, options=task.options)
        for path in paths
    }
    ledger = Ledger(out_dir)
    reused = {}
    for path, output in jobs:
        if not force and ledger.current(output, keys[str(path)], path):
            try:
                result = CalibrationResult.load(output)
            except InputError:
                continue  # an unreadable output is made again
            row = {"log": str(path), **calibration_row(result), "output": str(output)}
            reused[str(path)] = status_row({**row, "action": "skipped", "seconds": 0.0}, "ok")
    return _run(
        jobs, task, reused, ledger, keys, CALIBRATION_COLUMNS, scheduler, workers, progress, notes
    )


def apply_many(
    parameters,
    source,
    out_dir,
    *,
    read_options: dict | None = None,
    flag_outliers: bool = False,
    drift=None,
    temperature_column: str | None = None,
    force: bool = False,
    scheduler=None,
    workers: int | None = None,
    progress=None,
) -> BatchReport:
    """Correct every log of `source` with Eq. 4 and write `<name>.corrected.csv` (or .parquet).

    Parameters
    ----------
    parameters : str, os.PathLike or None
        A parameters file applied to every log, or a folder of `<name>.params.json` (the output
        folder of `calibrate_many`), one per log; or None with `drift` alone.
    source : str, os.PathLike or sequence of them
        A glob pattern, a folder, a file or a list of files.
    out_dir : str or os.PathLike
        The output folder (`--out-dir`).
    read_options : dict, optional
        Keyword arguments of `read_log`.
    flag_outliers : bool
        Add a boolean `outlier` column (`--flag-outliers`).
    drift : str or os.PathLike, optional
        A drift file whose k(t) is applied first (`--drift`).
    temperature_column : str, optional
        The logs' temperature column, with `drift` (`--temperature-column`). [degC]
    force : bool
        Correct logs whose output is newer than the log too (`--force`).
    scheduler : str or dask.distributed.Client, optional
        As in `calibrate_many`.
    workers : int, optional
        Workers of a local cluster.
    progress : callable, optional
        As in `calibrate_many`.

    Returns
    -------
    BatchReport
        One summary row per log, and where the summary was written.

    Raises
    ------
    InputError
        A source that names no log, or unusable parameters.

    Examples
    --------
    >>> import os, tempfile
    >>> import nlpcal
    >>> folder = tempfile.mkdtemp()
    >>> nlpcal.simulate(300, seed=0).to_csv(os.path.join(folder, "log0.csv"), index=False)
    >>> logs, out = os.path.join(folder, "*.csv"), os.path.join(folder, "out")
    >>> _ = nlpcal.calibrate_many(logs, out, options={"method": "joint"})
    >>> nlpcal.apply_many(out, logs, os.path.join(folder, "corrected")).counts()
    {'ok': 1}
    """
    out_dir = _out_dir(out_dir)
    notes: list = []
    paths = _paths(source, out_dir, notes)
    names = output_names(paths)
    folder = parameters is not None and Path(parameters).is_dir()
    if parameters is not None and not folder:
        load_parameters(parameters)  # a bad parameters file fails the whole run, once
    jobs = []
    for path in paths:
        params = parameters
        if folder:
            params = Path(parameters) / f"{names[path]}{PARAMS_SUFFIX}"
        suffix = ".parquet" if is_parquet(path) else ".csv"
        jobs.append((path, params, out_dir / f"{names[path]}{CORRECTED_TAG}{suffix}"))
    task = ApplyTask(dict(read_options or {}), flag_outliers, drift, temperature_column)
    keys = {
        str(path): digest(
            "apply",
            path,
            read_options=task.read_options,
            parameters=str(Path(params).resolve()) if params else None,
            flag_outliers=flag_outliers,
            drift=str(Path(drift).resolve()) if drift else None,
            temperature_column=temperature_column,
        )
        for path, params, _ in jobs
    }
    ledger = Ledger(out_dir)
    reused = {}
    for path, params, output in jobs:
        if not force and ledger.current(output, keys[str(path)], path, params, drift):
            row = {"log": str(path), "params": str(params or ""), "output": str(output)}
            reused[str(path)] = status_row({**row, "action": "skipped", "seconds": 0.0}, "ok")
    return _run(
        jobs, task, reused, ledger, keys, APPLY_COLUMNS, scheduler, workers, progress, notes
    )


def _paths(source, out_dir: Path, notes: list) -> list:
    """The logs of `source`, each once (`nlpcal.io.sources.distinct_files`, whose notes go to
    `notes`), less the files a batch writes into `out_dir` (a folder or pattern that holds the
    outputs of an earlier run)."""
    if isinstance(source, (list, tuple)):
        paths = distinct_files([Path(p) for p in source], notes)
    else:
        paths = log_paths(source, notes)
    out = out_dir.resolve()
    paths = [
        p
        for p in paths
        if not (
            p.resolve().parent == out
            and (
                p.name in (SUMMARY, LEDGER)
                or CORRECTED_TAG in p.name
                or p.name.endswith(PARAMS_SUFFIX)
            )
        )
    ]
    if not paths:
        raise InputError(f"no logs in {source}")
    return paths
