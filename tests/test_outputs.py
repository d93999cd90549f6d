"""Outputs that respect what they write to: a file is replaced atomically (a symbolic link's
target in its place, the link kept), a character device or a FIFO is written through, a
command's outputs are put in place together, the named-temporary-file writer of other systems
keeps the same promises, and a reader of stdout that goes away ends the command quietly.

Device nodes are made with mknod in a temporary folder: never the system's own /dev.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import signal
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from nlpcal.cli import main
from nlpcal.errors import InputError, WriteError
from nlpcal.io import files
from nlpcal.io.files import (
    Outputs,
    write_bytes_atomic,
    write_csv_atomic,
    write_json_atomic,
    write_text_atomic,
)

PNG = b"\x89PNG\r\n\x1a\n"
#: A file name of 255 characters: legal, but no temporary name beside it fits (NAME_MAX), so
#: that writing it fails after the earlier outputs of a command are complete, even as root.
UNWRITABLE_NAME = "x" * 251 + ".png"
#: Runs a command with the named temporary file writer forced (UNNAMED_FILES = False).
NAMED_WRITER = (
    "import sys; from nlpcal.io import files; files.UNNAMED_FILES = False; "
    "from nlpcal.cli import main; sys.exit(main(sys.argv[1:]))"
)
#: The named writer held after it filled its temporary file, until a signal ends it: a kill
#: that always lands between the write and the rename, however loaded the machine.
HELD_NAMED_WRITER = """
import signal, sys, time
# Ctrl-C as a terminal delivers it, also where the suite runs with SIGINT ignored (nohup, cmd &)
signal.signal(signal.SIGINT, signal.default_int_handler)
from nlpcal.io import files
files.UNNAMED_FILES = False
fill = files._fill
def held(fd, write, binary):
    fill(fd, write, binary)
    sys.stderr.write("filled\\n")
    sys.stderr.flush()
    time.sleep(120)
files._fill = held
from nlpcal.cli import main
sys.exit(main(sys.argv[1:]))
"""


def null_device(path: Path) -> int:
    """A character device node like /dev/null (1, 3) at `path`; its device number."""
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except PermissionError:
        pytest.skip("making a device node needs root")
    return os.stat(path).st_rdev


def debris(*folders: Path) -> list:
    """Temporary files a writer left behind."""
    return [p.name for folder in folders for p in folder.iterdir() if p.name.endswith(".tmp")]


@contextlib.contextmanager
def fifo_reader(path: Path):
    """A FIFO at `path` and a process reading it to the end; yields a list that receives the
    bytes read once the block ends (a reader still waiting after 60 s fails the test)."""
    os.mkfifo(path)
    reader = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; sys.stdout.buffer.write(open(sys.argv[1], 'rb').read())",
        ]
        + [str(path)],
        stdout=subprocess.PIPE,
    )
    received: list = []
    try:
        yield received
        try:
            received.append(reader.communicate(timeout=60)[0])
        except subprocess.TimeoutExpired:
            pytest.fail(f"nothing was written through the FIFO {path}")
    finally:
        if reader.poll() is None:
            reader.kill()
            reader.wait()


@pytest.fixture(params=["unnamed", "named"])
def writer(request, monkeypatch, tmp_path):
    """Both writers: unnamed temporary files (O_TMPFILE) and the named temporary file used where
    there are none, forced here."""
    if request.param == "unnamed":
        fd = files._unnamed_file(tmp_path)
        if fd is None:
            pytest.skip("no unnamed temporary files (O_TMPFILE) on this file system")
        os.close(fd)
    monkeypatch.setattr(files, "UNNAMED_FILES", request.param == "unnamed")
    return request.param


# --- the writers ----------------------------------------------------------------------------------

FRAME = pd.DataFrame({"bx": [1.5, -2.25], "by": [3.0, 4.125], "bz": [0.1, 0.2]})
WRITERS = {
    "text": (lambda path: write_text_atomic(path, "text\n"), b"text\n"),
    "bytes": (lambda path: write_bytes_atomic(path, PNG), PNG),
    "json": (lambda path: write_json_atomic(path, {"z_x": 1.5}), b'{\n  "z_x": 1.5\n}\n'),
    "csv": (lambda path: write_csv_atomic(path, FRAME), FRAME.to_csv(index=False).encode()),
}


@pytest.mark.parametrize("kind", WRITERS)
def test_a_file_is_replaced_keeping_its_permissions(writer, tmp_path, kind):
    write, expected = WRITERS[kind]
    path = tmp_path / "out"
    path.write_text("previous")
    path.chmod(0o640)
    write(path)
    assert path.read_bytes() == expected
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert debris(tmp_path) == []


@pytest.mark.parametrize("kind", WRITERS)
def test_a_symlink_stays_a_link_to_the_new_file(writer, tmp_path, kind):
    write, expected = WRITERS[kind]
    (tmp_path / "data").mkdir()
    target = tmp_path / "data" / "real"
    target.write_text("previous")
    link = tmp_path / "link"
    link.symlink_to(Path("data") / "real")
    write(link)
    assert link.is_symlink() and os.readlink(link) == str(Path("data") / "real")
    assert target.read_bytes() == expected
    dangling = tmp_path / "dangling"
    dangling.symlink_to("data/new")  # a link to a file not yet there: the file is made
    write(dangling)
    assert dangling.is_symlink() and (tmp_path / "data" / "new").read_bytes() == expected
    assert debris(tmp_path, tmp_path / "data") == []


@pytest.mark.parametrize("kind", WRITERS)
def test_a_character_device_is_written_through(writer, tmp_path, kind):
    write, _ = WRITERS[kind]
    path = tmp_path / "null"
    device = null_device(path)
    write(path)
    assert stat.S_ISCHR(os.lstat(path).st_mode) and os.lstat(path).st_rdev == device
    assert debris(tmp_path) == []


@pytest.mark.parametrize("kind", WRITERS)
def test_a_fifo_is_written_through(writer, tmp_path, kind):
    write, expected = WRITERS[kind]
    path = tmp_path / "fifo"
    with fifo_reader(path) as received:
        write(path)
    assert received == [expected]
    assert stat.S_ISFIFO(os.lstat(path).st_mode)
    assert debris(tmp_path) == []


def test_an_open_descriptor_is_written_through_a_copy(tmp_path):
    # A link to /proc/self/fd/N (as /dev/stdout is) names this process's open file N: it is
    # written through, as a shell writes `> /dev/stdout`, and the link stays.
    read, written = os.pipe()
    try:
        link = tmp_path / "stdout"
        link.symlink_to(f"/proc/self/fd/{written}")
        write_text_atomic(link, "through\n")
        os.close(written)
        written = -1
        assert os.read(read, 100) == b"through\n"
        assert link.is_symlink()
    finally:
        os.close(read)
        if written >= 0:
            os.close(written)


def test_what_no_output_is_written_to_is_refused(writer, tmp_path):
    folder = tmp_path / "folder"
    folder.mkdir()
    block = tmp_path / "block"
    try:  # a major number for local use: no driver behind it, and nothing opens it
        os.mknod(block, 0o600 | stat.S_IFBLK, os.makedev(240, 0))
    except PermissionError:
        pytest.skip("making a device node needs root")
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(tmp_path / "socket"))
    try:
        for path, mode in ((folder, stat.S_ISDIR), (block, stat.S_ISBLK)):
            with pytest.raises(InputError):
                write_text_atomic(path, "text")
            assert mode(os.lstat(path).st_mode)
        with pytest.raises(InputError):
            write_text_atomic(tmp_path / "socket", "text")
        assert stat.S_ISSOCK(os.lstat(tmp_path / "socket").st_mode)
    finally:
        listener.close()
    assert debris(tmp_path) == []


def test_an_interrupted_write_leaves_the_file_and_no_debris(writer, tmp_path):
    path = tmp_path / "out.json"
    path.write_text("previous")
    seen = []

    def interrupted(handle):
        handle.write("half")
        seen.append(debris(tmp_path))
        raise KeyboardInterrupt  # what SIGINT, or SIGTERM through the command line, raises

    with pytest.raises(KeyboardInterrupt), Outputs() as outputs:
        outputs.write(path, interrupted)
    assert path.read_text() == "previous"
    assert debris(tmp_path) == []
    # the writer forced is the one at work: only the named one shows a file while it writes
    assert len(seen[0]) == (1 if writer == "named" else 0)


# --- several outputs together ---------------------------------------------------------------------


def test_outputs_are_put_in_place_only_when_all_are_complete(writer, tmp_path, capsys):
    first = tmp_path / "first.json"
    first.write_text("previous")

    def failing(handle):
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(WriteError), Outputs() as outputs:
        outputs.json(first, {"a": 1})
        outputs.text(None, "to stdout")  # written through only at the commit
        outputs.write(tmp_path / "second.png", failing, binary=True)
    assert first.read_text() == "previous"
    assert capsys.readouterr().out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["first.json"]


def test_a_reader_gone_from_stdout_leaves_the_other_outputs_in_place(writer, tmp_path):
    # the reader of stdout went away having what it wanted: the complete files still take place
    first = tmp_path / "first.json"
    first.write_text("previous")

    def gone(handle):
        raise BrokenPipeError(errno.EPIPE, "Broken pipe")

    with pytest.raises(BrokenPipeError), Outputs() as outputs:
        outputs.json(first, {"a": 1})
        outputs.write(None, gone)
    assert json.loads(first.read_text()) == {"a": 1}
    assert debris(tmp_path) == []


def test_two_outputs_to_one_place_are_refused(tmp_path):
    with pytest.raises(InputError, match="share one destination"), Outputs() as outputs:
        outputs.text(None, "a document")
        outputs.bytes("-", PNG)  # a figure after a document on stdout: neither readable
    with pytest.raises(InputError, match="share one destination"), Outputs() as outputs:
        outputs.text(tmp_path / "out.txt", "a")
        outputs.text(tmp_path / "." / "out.txt", "b")
    assert not (tmp_path / "out.txt").exists()
    with Outputs() as outputs:  # a character device takes any number of outputs
        device = tmp_path / "null"
        null_device(device)
        outputs.text(device, "a")
        outputs.bytes(device, PNG)


@pytest.mark.parametrize("output", [None, "-"])
def test_a_plot_to_the_stdout_of_a_document_is_refused_before_any_work(inputs, capsys, output):
    argv = ["calibrate", str(inputs / "log.csv"), "--unit", "nT", "--plot", "-"]
    code = main(argv + ([] if output is None else ["-o", output]))
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""
    assert "share one destination" in captured.err and "verdict" not in captured.err


def test_a_link_into_a_missing_folder_is_refused_before_any_work(tmp_path):
    link = tmp_path / "params.json"
    link.symlink_to(tmp_path / "nowhere" / "params.json")
    with pytest.raises(InputError, match="does not exist"):
        files.check_output_path(link)


def test_a_failed_write_through_leaves_the_files(writer, tmp_path):
    first = tmp_path / "first.json"
    first.write_text("previous")
    device = tmp_path / "null"
    null_device(device)

    def failing(handle):
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(WriteError), Outputs() as outputs:
        outputs.json(first, {"a": 1})
        outputs.write(device, failing)
    assert first.read_text() == "previous"
    assert debris(tmp_path) == []


# --- every command --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A folder of inputs for every command: a log, its parameters, an export of them, the
    compass and drift replicas, a compass calibration and its attitudes."""
    d = tmp_path_factory.mktemp("inputs")
    made = [
        ["simulate", "-n", "300", "--seed", "3", "-o", d / "log.csv"],
        ["simulate", "--preset", "qiu2017", "-n", "40", "-o", d / "q"],
        ["simulate", "--preset", "liu2022", "-n", "30", "-o", d / "l"],
        ["calibrate", d / "log.csv", "--method", "joint", "--unit", "nT", "-o", d / "params.json"],
        ["export", d / "params.json", "--format", "matlab", "-o", d / "matlab.txt"],
        ["compass", "calibrate", d / "q" / "turns.csv", *COMPASS_COLUMNS, "-o", d / "c.json"],
        ["compass", "attitude", d / "c.json", d / "q" / "test.csv", "-o", d / "att.csv"],
    ]
    for argv in made:
        assert main([str(a) for a in argv] + ["-q"]) == 0, argv
    return d


COMPASS_COLUMNS = [
    *("--mag-columns", "mx_nT", "my_nT", "mz_nT"),
    *("--acc-columns", "ax_g", "ay_g", "az_g"),
    *("--turn-column", "turn"),
]
ANGLES = ["--angles-deg", "0.1", "0.2", "0.3", "--reference-field", "55000"]
LOG, PARAMS = "{d}/log.csv", "{d}/params.json"
#: Each command's outputs: (argv with {out} for the output, or {dir} for an output folder and
#: the name of the output in it; how the output is checked).
COMMANDS = {
    "simulate": (["simulate", "-n", "50", "-o", "{out}"], "csv"),
    "simulate folder": (["simulate", "--preset", "qiu2017", "-n", "40", "-o", "{dir}"], "csv"),
    "calibrate": (["calibrate", LOG, "--method", "joint", "-o", "{out}"], "json"),
    "calibrate --plot": (["calibrate", LOG, "--method", "joint", "--plot", "{out}"], "png"),
    "apply": (["apply", PARAMS, LOG, "-o", "{out}"], "csv"),
    "apply --plot": (["apply", PARAMS, LOG, "--plot", "{out}"], "png"),
    "compare": (["compare", LOG, "--cycles", "2", "--cg-max-iter", "20", "-o", "{out}"], "json"),
    "compare --plot": (
        ["compare", LOG, "--cycles", "2", "--cg-max-iter", "20", "--plot", "{out}"],
        "png",
    ),
    "orthogonality worst-case": (["orthogonality", "worst-case", *ANGLES, "-o", "{out}"], "json"),
    "orthogonality map": (
        ["orthogonality", "map", *ANGLES, "--step-deg", "10", "-o", "{out}"],
        "png",
    ),
    "orthogonality map --csv": (
        ["orthogonality", "map", *ANGLES, "--step-deg", "10", "--csv", "{out}"],
        "csv",
    ),
    "orthogonality invert": (["orthogonality", "invert", LOG, "-o", "{out}"], "json"),
    "drift fit": (
        [
            *("drift", "fit", "{d}/l/drift.csv", "--temperature-column", "temp_c"),
            *("--reference-column", "proton_nT", "--base-temperature", "7.3", "-o", "{out}"),
        ],
        "json",
    ),
    "compass calibrate": (
        ["compass", "calibrate", "{d}/q/turns.csv", *COMPASS_COLUMNS, "-o", "{out}"],
        "json",
    ),
    "compass attitude": (
        ["compass", "attitude", "{d}/c.json", "{d}/q/test.csv", "-o", "{out}"],
        "csv",
    ),
    "compass evaluate": (
        [
            *("compass", "evaluate", "{d}/att.csv", "--truth-columns"),
            *("true_roll_deg", "true_pitch_deg", "true_heading_deg", "-o", "{out}"),
        ],
        "json",
    ),
    "export": (["export", PARAMS, "--format", "c-header", "-o", "{out}"], "text"),
    "import": (["import", "{d}/matlab.txt", "--format", "matlab", "-o", "{out}"], "json"),
    "report": (["report", PARAMS, LOG, "-o", "{out}"], "html"),
    "batch calibrate": (["batch", "calibrate", LOG, "--out-dir", "{dir}"], "json"),
    "batch calibrate summary": (["batch", "calibrate", LOG, "--out-dir", "{dir}"], "csv"),
    "batch apply": (["batch", "apply", PARAMS, LOG, "--out-dir", "{dir}"], "csv"),
}
#: The output checked of a command writing a folder.
IN_FOLDER = {
    "simulate folder": "turns.csv",
    "batch calibrate": "log.params.json",
    "batch calibrate summary": "summary.csv",
    "batch apply": "log.corrected.csv",
}


def command_output(name: str, folder: Path) -> Path:
    """Where the output of command `name` goes in `folder` (made for it)."""
    if name in IN_FOLDER:
        (folder / "out").mkdir()
        return folder / "out" / IN_FOLDER[name]
    suffix = {"json": ".json", "csv": ".csv", "png": ".png", "html": ".html", "text": ".h"}
    return folder / f"out{suffix[COMMANDS[name][1]]}"


def run_command(name: str, inputs: Path, output: Path, capsys) -> int:
    argv, _ = COMMANDS[name]
    values = {"d": inputs, "out": output, "dir": output.parent}
    status = main([part.format(**values) for part in argv] + ["-q"])
    capsys.readouterr()
    return status


def check_output(kind: str, data: bytes) -> None:
    """`data` is a whole output of its kind."""
    if kind == "json":
        json.loads(data)
    elif kind == "csv":
        assert len(pd.read_csv(io.BytesIO(data))) > 0
    elif kind == "png":
        assert data.startswith(PNG)
    elif kind == "html":
        assert data.rstrip().endswith(b"</html>")
    else:
        assert data.strip()


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_writes_through_a_character_device(inputs, tmp_path, capsys, name):
    output = command_output(name, tmp_path)
    device = null_device(output)
    assert run_command(name, inputs, output, capsys) == 0
    assert stat.S_ISCHR(os.lstat(output).st_mode) and os.lstat(output).st_rdev == device
    assert debris(output.parent) == []


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_writes_through_a_fifo(inputs, tmp_path, capsys, name):
    output = command_output(name, tmp_path)
    with fifo_reader(output) as received:
        assert run_command(name, inputs, output, capsys) == 0
    check_output(COMMANDS[name][1], received[0])
    assert stat.S_ISFIFO(os.lstat(output).st_mode)
    assert debris(output.parent) == []


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_keeps_a_symlink(inputs, tmp_path, capsys, name):
    output = command_output(name, tmp_path)
    (tmp_path / "data").mkdir()
    target = tmp_path / "data" / "real"
    target.write_text("previous")
    output.symlink_to(target)
    assert run_command(name, inputs, output, capsys) == 0
    assert output.is_symlink() and os.readlink(output) == str(target)
    check_output(COMMANDS[name][1], target.read_bytes())
    assert debris(output.parent, target.parent) == []


#: Commands with two outputs: (argv with {first}, the output that can be written, and {bad},
#: one that cannot).
SEVERAL = {
    "calibrate": ["calibrate", LOG, "--method", "joint", "-o", "{first}", "--plot", "{bad}"],
    "calibrate to stdout": ["calibrate", LOG, "--method", "joint", "--plot", "{bad}"],
    "apply": ["apply", PARAMS, LOG, "-o", "{first}", "--plot", "{bad}"],
    "compare": [
        "compare",
        LOG,
        "--cycles",
        "2",
        "--cg-max-iter",
        "20",
        "-o",
        "{first}",
        "--plot",
        "{bad}",
    ],
    "orthogonality map": ["orthogonality", "map", *ANGLES, "-o", "{bad}", "--csv", "{first}"],
    "orthogonality map --csv": ["orthogonality", "map", *ANGLES, "-o", "{first}", "--csv", "{bad}"],
}


@pytest.mark.parametrize(
    "name, named",
    [(name, False) for name in SEVERAL] + [("calibrate", True), ("orthogonality map", True)],
)
def test_a_failed_output_leaves_every_other_as_it_was(
    inputs, tmp_path, capsys, monkeypatch, name, named
):
    monkeypatch.setattr(files, "UNNAMED_FILES", not named)
    first, bad = tmp_path / "first", tmp_path / UNWRITABLE_NAME
    first.write_text("previous")
    values = {"d": inputs, "first": first, "bad": bad}
    status = main([part.format(**values) for part in SEVERAL[name]])
    out, err = capsys.readouterr()
    assert first.read_text() == "previous" and out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["first"]  # no debris, no output
    assert status == 2 and "cannot be written" in err, err


def test_a_folder_preset_writes_all_its_files_or_none(writer, tmp_path, capsys):
    folder = tmp_path / "replica"
    folder.mkdir()
    (folder / "base.csv").write_text("previous")
    (folder / "truth.json").mkdir()  # the last of its files cannot be written
    status = main(["simulate", "--preset", "liu2022", "-n", "30", "-o", str(folder)])
    assert status == 2 and "is a directory" in capsys.readouterr().err
    assert (folder / "base.csv").read_text() == "previous"
    assert sorted(p.name for p in folder.iterdir()) == ["base.csv", "truth.json"]


def test_a_failed_batch_log_leaves_a_device_in_place_of_its_output(tmp_path, capsys):
    # A log that fails loses the output an earlier run wrote; a device there holds none.
    log = tmp_path / "bad.csv"
    log.write_text("bx,by,bz\n1,2,3\n")
    (tmp_path / "out").mkdir()
    output = tmp_path / "out" / "bad.params.json"
    device = null_device(output)
    status = main(["batch", "calibrate", str(log), "--out-dir", str(tmp_path / "out"), "-q"])
    capsys.readouterr()
    assert status == 2
    assert stat.S_ISCHR(os.lstat(output).st_mode) and os.lstat(output).st_rdev == device


# --- killed runs, with the named temporary file writer --------------------------------------------


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_killed_write_through_the_named_writer_leaves_nothing(tmp_path, signum):
    output = tmp_path / "log.csv"
    output.write_text("previous")
    command = [sys.executable, "-c", HELD_NAMED_WRITER, "simulate", "-n", "2000", "-o", str(output)]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    try:
        assert process.stderr.readline() == "filled\n", "the writer never held"
        assert debris(tmp_path), "the named temporary file is not there"
        process.send_signal(signum)  # while the complete file waits under its temporary name
        _, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == (143 if signum == signal.SIGTERM else 130), err
    assert output.read_text() == "previous"
    assert debris(tmp_path) == []


# --- a reader that goes away ----------------------------------------------------------------------


def test_simulate_into_head_ends_quietly_with_141(tmp_path):
    simulate = subprocess.Popen(
        [sys.executable, "-m", "nlpcal", "simulate", "-n", "20000"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    head = subprocess.run(["head", "-n", "1"], stdin=simulate.stdout, capture_output=True)
    simulate.stdout.close()
    err = simulate.stderr.read()
    simulate.wait(timeout=60)
    assert head.stdout == b"bx,by,bz\n"
    assert simulate.returncode == 141 and err == b""


def test_a_fifo_whose_reader_leaves_ends_quietly_with_141(tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    quitter = subprocess.Popen(  # opens the FIFO and closes it without reading
        [sys.executable, "-c", "import os, sys; os.close(os.open(sys.argv[1], os.O_RDONLY))"]
        + [str(fifo)]
    )
    try:
        status = main(["simulate", "-n", "20000", "-o", str(fifo)])  # 0.8 MB: more than a pipe
    finally:
        quitter.kill()
        quitter.wait()
    assert status == 141 and capsys.readouterr().err == ""
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


STDOUT_COMMANDS = {
    "calibrate": ["calibrate", LOG, "--method", "joint"],
    "apply": ["apply", PARAMS, LOG],
    "stats": ["stats", LOG, "--json"],
    "export": ["export", PARAMS, "--format", "c-header"],
    "compass attitude": ["compass", "attitude", "{d}/c.json", "{d}/q/test.csv"],
}


@pytest.mark.parametrize("name", STDOUT_COMMANDS)
def test_a_closed_stdout_ends_every_command_quietly_with_141(inputs, name):
    read, written = os.pipe()
    os.close(read)  # the reader is gone before anything is written
    try:
        argv = [part.format(d=inputs) for part in STDOUT_COMMANDS[name]]
        done = subprocess.run(
            [sys.executable, "-m", "nlpcal", *argv, "-q"],
            stdout=written,
            stderr=subprocess.PIPE,
            timeout=120,
        )
    finally:
        os.close(written)
    assert done.returncode == 141 and done.stderr == b""
