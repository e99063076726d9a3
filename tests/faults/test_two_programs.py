"""Several programs at once, some killed outright: the client that holds a lock is never
broken by another, every refusal is one line naming the holder, and nothing that a
command reported as stored is lost."""

import json
import os
import random
import signal
import subprocess
import sys
import time

import pytest

from robox.offline.sdcard import format_image, fsck_image, get_file, list_image

CLI = [sys.executable, "-m", "robox.cli"]


def one_line_refusal(err: bytes) -> bool:
    lines = err.decode().strip().splitlines()
    return len(lines) == 1 and lines[0].startswith("robox-cli: error: ") and \
        " is in use by PID " in lines[0]


@pytest.fixture
def env(tmp_path):
    # (temporary files here too: a host killed with -9 leaves its job's copy behind)
    (tmp_path / "tmp").mkdir()
    return {**os.environ, "XDG_RUNTIME_DIR": str(tmp_path / "runtime"),
            "XDG_STATE_HOME": str(tmp_path / "host-state"), "TMPDIR": str(tmp_path / "tmp")}


def test_status_loops_beside_send_job_wait_never_break_it(tmp_path, env):
    """Three programs ask for the status over and over while a job uploads and prints:
    each of their runs answers or is refused in one line; the print ends as it should."""
    state = tmp_path / "printer"
    subprocess.run([*CLI, "sim", "serve", "--detach", "--state", str(state)], env=env,
                   check=True, capture_output=True, timeout=120)
    job = tmp_path / "part.gcode"
    job.write_bytes(b"G28 X Y\n" + b"G1 X20 Y20 F6000\nG1 X150 Y100\n" * 3000)
    try:
        # (a status may hold the port the moment send-job opens it: send-job waits for
        # it, as a user running both would have it do; the status runs are refused)
        send = subprocess.Popen([*CLI, "--wait-lock", "60", "--device", f"sim:{state}",
                                 "send-job", str(job), "--raw", "--id", "part", "--wait",
                                 "--json"], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
        answered = refused = 0
        while send.poll() is None:
            loops = [subprocess.Popen([*CLI, "--device", f"sim:{state}", "status"], env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE)
                     for _ in range(3)]
            for loop in loops:
                out, err = loop.communicate(timeout=120)
                if loop.returncode == 0:
                    answered += 1
                else:
                    assert loop.returncode == 1 and one_line_refusal(err), err.decode()
                    refused += 1
        out, err = send.communicate(timeout=10)
        assert send.returncode == 0, err.decode()
        assert b'"errors": []' in out
        assert refused > 0  # they did meet
    finally:
        subprocess.run([*CLI, "sim", "stop", "--state", str(state)], env=env,
                       capture_output=True, timeout=120)
    assert [f["id"] for f in list_image(state / "sdcard.img")["files"]][-1] == "part"


def parts(tmp_path, count: int) -> list:
    out = []
    for n in range(count):
        part = tmp_path / f"part{n}.gcode"
        part.write_bytes(f"G1 X{n + 1}\r".encode() * (3000 + 500 * n))  # stored as it is
        out.append(part)
    return out


def put(card, part, *options: str) -> subprocess.Popen:
    return subprocess.Popen([*CLI, *options, "sdcard", "put", str(card), str(part), "--id",
                             part.stem, "--job"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)


def test_writers_at_once_on_one_image_store_or_are_refused_and_lose_nothing(tmp_path):
    card = tmp_path / "card.img"
    format_image(card, 16384)
    files = parts(tmp_path, 5)
    writers = [(p, put(card, p)) for p in files]
    stored = []
    for part, writer in writers:
        _, err = writer.communicate(timeout=300)
        if writer.returncode == 0:
            stored.append(part)
        else:
            assert writer.returncode == 1 and one_line_refusal(err), err.decode()
    assert stored  # one at least held the image
    on_card = {f["id"] for f in list_image(card)["files"]}
    assert {p.stem for p in stored} == on_card
    for part in stored:
        assert get_file(card, part.stem) == part.read_bytes()
    assert fsck_image(card)["project"]["action"] != "format"


@pytest.mark.parametrize("seed", range(4))
def test_a_writer_killed_outright_leaves_the_others_stored(tmp_path, seed):
    """Writers that wait for the lock; one is killed with -9 at a random moment. Those
    that reported success are on the card, whole; the card mounts."""
    rng = random.Random(seed)
    card = tmp_path / "card.img"
    format_image(card, 16384)
    files = parts(tmp_path, 4)
    writers = [(p, put(card, p, "--wait-lock", "120")) for p in files]
    victim = rng.randrange(len(writers))
    time.sleep(rng.uniform(0.0, 1.0))
    writers[victim][1].send_signal(signal.SIGKILL)
    stored = []
    for part, writer in writers:
        writer.communicate(timeout=300)
        if writer.returncode == 0:
            stored.append(part)
        else:
            assert writer is writers[victim][1] and writer.returncode == -signal.SIGKILL
    assert len(stored) >= len(files) - 1
    assert fsck_image(card)["project"]["action"] != "format"
    on_card = {f["id"] for f in list_image(card)["files"]}
    for part in stored:
        assert part.stem in on_card and get_file(card, part.stem) == part.read_bytes()


CUT = """
import os, sys
from robox import fileio
from robox.host import catalogue
calls = [0]
def dying(name, real):
    def call(*args, **kwargs):
        calls[0] += 1
        if calls[0] == int(sys.argv[1]):
            os._exit(9)  # the host dies here, as with kill -9: no clean-up runs
        return real(*args, **kwargs)
    return call
for name in ("chmod", "fsync", "replace", "open", "close"):
    setattr(fileio.os, name, dying(name, getattr(os, name)))
catalogue.record("RBX01-0001", "new", 2, 2, True)
"""


def test_the_host_catalogue_cut_at_every_step_of_its_write_is_old_or_new(tmp_path,
                                                                          monkeypatch):
    """The host dies at each file-system call of a catalogue update in turn: the
    catalogue then holds the old entries or the new ones, never a broken file."""
    import json

    from robox.host import catalogue

    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path)}
    path = tmp_path / "robox" / "cards" / "RBX01-0001.json"
    step, ends = 0, set()
    while True:
        step += 1
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"files": {"old": {"size": 1}}}))
        died = subprocess.run([sys.executable, "-c", CUT, str(step)], env=env,
                              capture_output=True, timeout=60)
        files = set(json.loads(path.read_text())["files"])
        assert files in ({"old"}, {"old", "new"}), (step, files)
        ends.add(frozenset(files))
        if died.returncode == 0:
            break
        assert died.returncode == 9, died.stderr.decode()
    assert step > 4 and ends == {frozenset({"old"}), frozenset({"old", "new"})}
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    assert set(catalogue.load("RBX01-0001")) == {"old", "new"}



@pytest.mark.parametrize("chunks", [3, 57, 180])
def test_a_client_killed_mid_upload_frees_the_port_for_the_next(tmp_path, env, chunks):
    """send-job is killed with -9 after `chunks` chunks of its upload: the kernel drops its
    port lock with it, and the next client resumes the upload to a whole file."""
    state = tmp_path / "printer"
    subprocess.run([*CLI, "sim", "serve", "--detach", "--state", str(state)], env=env,
                   check=True, capture_output=True, timeout=120)
    job = tmp_path / "part.gcode"
    job.write_bytes(b"G28 X Y\n" + b"".join(f"G1 X{20 + n % 150} Y{20 + n % 100} F6000\n"
                                            .encode() for n in range(10_000)))
    try:  # -v: each command on stderr, so the kill lands after a known chunk
        first = subprocess.Popen([*CLI, "-v", "--device", f"sim:{state}", "send-job",
                                  str(job), "--raw", "--id", "part"], env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        seen = 0
        while seen < chunks:
            line = first.stderr.readline()
            assert line, "the upload ended first"
            seen += b"sent 0x91" in line
        first.send_signal(signal.SIGKILL)
        first.communicate(timeout=60)
        again = subprocess.run([*CLI, "--device", f"sim:{state}", "send-job", str(job),
                                "--raw", "--id", "part", "--resume", "--json"], env=env,
                               capture_output=True, timeout=300)
        assert again.returncode == 0, again.stderr.decode()
        assert first.returncode == -signal.SIGKILL
        summary = json.loads(again.stdout)
        assert summary["resumed_from_byte"] >= chunks * 512 and not summary["already_stored"]
    finally:
        subprocess.run([*CLI, "sim", "stop", "--state", str(state)], env=env,
                       capture_output=True, timeout=120)
    expected = b"\r".join(line for line in job.read_bytes().split(b"\n") if line) + b"\r"
    assert get_file(state / "sdcard.img", "part") == expected
