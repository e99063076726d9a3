"""The build backend: setuptools, plus the compiled core where it can be built.

A wheel (`pip install .`, `pip wheel .`, `python -m build`) compiles the firmware
model's hot modules (setup.py, NATIVE_MODULES) with mypyc into C extensions; the same
.py files stay beside them as the pure-Python fallback, and `robox.native.describe()`
tells which one runs. `ROBOX_NATIVE` in the environment chooses:

- unset (or `auto`): compiled when it can be; with no C compiler, or when compiling
  fails, the wheel is pure Python and one line on stderr says why;
- `1`: compiled or nothing (a failure to compile fails the build);
- `0`: pure Python.

A compiled build takes minutes (about 3 on a two-core x86-64 machine, 5 of CPU; with GCC
it compiles the core twice around a training run, see BuildExt). pip's `-q` hides what
a backend prints, so its stages and a line every 30 s go to the terminal (/dev/tty)
where there is one, else to stderr (`pip install -v` shows them).

An editable install (`pip install -e .`) is always pure Python: compiled modules would
shadow later edits of the sources. Each kind of build keeps its own build directory
(build/native, build/pure), so a pure wheel never picks up an extension a compiled
build left behind.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import shutil
import sys
import sysconfig
import tempfile
import threading
import time

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F403  (the standard hooks, unchanged)
from setuptools.command.build_ext import build_ext
from setuptools.errors import CompileError, LinkError

MYPYC = "mypy[mypyc]>=2.4"  # librt.vecs (src/robox/packed.py)
CHOICE = "ROBOX_NATIVE"
BUILD = "ROBOX_BUILD_KIND"  # what setup.py builds: "native" or "pure" (set here only)


def _choice() -> str:
    value = os.environ.get(CHOICE, "auto").strip().lower() or "auto"
    if value not in ("auto", "0", "1"):
        raise SystemExit(f"robox: {CHOICE} must be 1, 0 or auto, not {value!r}")
    return value


def _say(text: str) -> None:
    print(f"robox: {text}", file=sys.stderr)


def _terminal():
    """Where progress goes: the terminal, which pip's -q does not silence, else stderr."""
    try:
        return open("/dev/tty", "w", encoding="utf-8")
    except OSError:
        return None


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.0f} min {seconds % 60:.0f} s" if seconds >= 60 else \
        f"{seconds:.0f} s"


@contextlib.contextmanager
def stage(text: str, tick_s: float = 30.0):
    """Say that a long build step began, that it still runs every `tick_s` and when it
    ended (the build's own process: a thread here waits, it does no work)."""
    tty = _terminal()
    out = tty or sys.stderr
    started = time.monotonic()

    def say(line: str) -> None:  # ("robox build:", apart from the one-line "robox:" notes)
        with contextlib.suppress(OSError, ValueError):
            print(f"robox build: {line}", file=out, flush=True)

    say(f"{text} ...")
    done = threading.Event()

    def ticking() -> None:
        while not done.wait(tick_s):
            say(f"{text}: {_minutes(time.monotonic() - started)} so far")

    ticker = threading.Thread(target=ticking, daemon=True)
    ticker.start()
    try:
        yield
    finally:
        done.set()
        ticker.join()
        say(f"{text}: done in {_minutes(time.monotonic() - started)}")
        if tty is not None:
            tty.close()


# The compiled core is one shared library of every module's C (one file per module, so
# that they compile side by side on the machine's cores). By default a shared library's
# functions may be replaced by another library's of the same name at load time, so the
# compiler neither inlines one into another nor calls it directly: these let it (Python
# finds a module by its exported PyInit_ function alone, which Python's headers keep
# visible). They change no arithmetic: no FMA, no fast math.
SPEED_FLAGS = ["-fno-semantic-interposition", "-fvisibility=hidden", "-fno-plt"]

# Where the compiler is GCC, the core is optimised as one program at link time (LTO:
# the modules' functions call each other at every step, and inlining across their files
# is what one file would give) and from a profile: it is compiled first with counters,
# run on a training job (robox_train.py), then compiled again knowing which branches
# and calls are hot. Neither changes what the code computes (the same C, the same
# floating-point rules); they only choose how it is laid out and inlined.
LTO_COMPILE = ["-flto"]
PROFILE_GENERATE = ["-fprofile-generate", "-fprofile-update=single"]
PROFILE_GENERATE_LINK = ["-fprofile-generate"]
PROFILE_USE = ["-fprofile-use", "-fprofile-partial-training", "-Wno-missing-profile"]
PROFILE_USE_LINK = ["-fprofile-use", "-fprofile-partial-training"]
# what the training run imports besides the package and mypyc's runtime (the commands
# it runs are robox-cli's: click; the upload goes through pyusb's API)
TRAINING = ["click>=8.1", "pyusb>=1.2"]
TRAINER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "robox_train.py")
TRAINING_TIMEOUT_S = 900
NATIVE_BUILD = "native_build.json"  # in the package: how its core was optimised

# Compiled functions whose whole work is what one C expression does and mypyc cannot
# write: the build gives them that expression as their body, in a copy of the C mypyc
# wrote (where the definition is not found, mypyc's compiled Python body stays, and a
# line says so). carith.f32, a double rounded to a C float, runs a dozen times a move;
# C's conversion is one instruction that rounds as the printer's soft floats do (to
# nearest, ties to even, overflow to an infinity).
C_BODIES = {
    "double CPyDef_carith___f32(double cpy_r_value)": "return (double)(float)cpy_r_value;",
}


def replace_bodies(text: str, bodies: dict[str, str]) -> tuple[str, list[str]]:
    """`text` (C as mypyc writes it: a definition's signature and `{` on one line, its
    closing `}` alone at the start of a line) with the body of each function whose
    signature `bodies` names replaced by the one given; and the signatures not found."""
    missing = []
    for signature, body in bodies.items():
        start = text.find(f"\n{signature} {{\n")
        end = text.find("\n}\n", start) if start >= 0 else -1
        if end < 0:
            missing.append(signature)
            continue
        opened = start + len(signature) + 3  # past "\n", the signature and " {"
        text = f"{text[:opened]}\n    {body}{text[end:]}"
    return text, missing


class BuildExt(build_ext):
    """setup.py's build_ext: its stages on the terminal, the core's files compiled side by
    side, SPEED_FLAGS where the compiler takes them, and with GCC the core optimised at
    link time and from a training run's profile (LTO_COMPILE, PROFILE_GENERATE)."""

    def build_extensions(self):
        flags = [flag for flag in SPEED_FLAGS if self._takes(flag)]
        missing = set(C_BODIES)
        for ext in self.extensions:
            ext.sources = [self._with_bodies(source, missing) for source in ext.sources]
            ext.extra_compile_args = [*ext.extra_compile_args, *flags]
        for signature in sorted(missing):
            _say(f"kept mypyc's own body for {signature.split('(')[0].split()[-1]} (its "
                 "definition was not found as expected in the C mypyc wrote)")
        _compile_side_by_side(self.compiler, _cores())
        # the library holding every module's C (the others are each module's small shim)
        core = max(self.extensions, key=lambda ext: len(ext.sources))
        compile_args, link_args = list(core.extra_compile_args), list(core.extra_link_args)
        lto, gcc = self._whole_program()
        # (GCC spreads the link-time work over the cores; the optimisation level is
        # given again at the link, where the functions are finally compiled)
        link_lto = [f"-flto={_cores()}" if gcc else "-flto",
                    *[arg for arg in compile_args if arg.startswith("-O")]]

        def build(compile_extra: list[str], link_extra: list[str], what: str,
                  only_core: bool = False) -> None:
            core.extra_compile_args = [*compile_args, *compile_extra]
            core.extra_link_args = [*link_args, *link_extra]
            everything = self.extensions
            if only_core:  # (the shims are built already)
                self.extensions = [core]
            try:
                with stage(f"compiled core: {what}"):
                    super(BuildExt, self).build_extensions()
            finally:
                self.extensions = everything

        # Each compile below builds and links afresh: a library an earlier build (or step)
        # left may look up to date by its files' times, and be the wrong kind.
        self.force = self.compiler.force = True
        if lto and gcc:
            self._forget_counts()  # (the counters add to what they find)
            try:
                build([*LTO_COMPILE, *PROFILE_GENERATE], [*link_lto, *PROFILE_GENERATE_LINK],
                      "compiling the C with counters")
            except (CompileError, LinkError) as error:
                _say(f"the core did not compile with counters ({_reason(error)}); it is "
                     "compiled without a training run")
            else:
                with stage("compiled core: the training run"):
                    failed = self._train()
                if failed:
                    _say(f"the training run failed ({failed}); the core is compiled "
                         "without its profile")
                else:
                    try:
                        build([*LTO_COMPILE, *PROFILE_USE], [*link_lto, *PROFILE_USE_LINK],
                              "compiling the C with the training run's counts",
                              only_core=True)
                        return self._record(link_time=True, profile=True)
                    except (CompileError, LinkError) as error:
                        _say(f"the core did not compile with the training run's counts "
                             f"({_reason(error)}); it is compiled without them")
                build(LTO_COMPILE, link_lto, "compiling the C, optimised at link time",
                      only_core=True)
                return self._record(link_time=True, profile=False)
        if lto:
            try:
                build(LTO_COMPILE, link_lto, "compiling the C, optimised at link time")
                return self._record(link_time=True, profile=False)
            except (CompileError, LinkError) as error:
                _say(f"the core did not compile optimised at link time ({_reason(error)}); "
                     "it is compiled file by file")
        build([], [], "compiling the C (the long part)")
        return self._record(link_time=False, profile=False)

    def _record(self, link_time: bool, profile: bool) -> None:
        """How the core was optimised, in the package (robox.native.describe() says it)."""
        import json

        folder = os.path.join(self.build_lib, "robox")
        os.makedirs(folder, exist_ok=True)
        with open(os.path.join(folder, NATIVE_BUILD), "w", encoding="utf-8") as f:
            json.dump({"link_time": link_time, "profile": profile}, f)
            f.write("\n")

    def _whole_program(self) -> tuple[bool, bool]:
        """Whether the compiler optimises a shared library at link time (LTO_COMPILE),
        and whether it is GCC with its profile counters (PROFILE_GENERATE)."""
        if self.compiler.compiler_type != "unix":
            return False, False
        if not self._links("", LTO_COMPILE, ["-flto"]):
            return False, False
        gcc = "#if defined(__clang__) || !defined(__GNUC__)\n#error not GCC\n#endif\n"
        return True, self._links(gcc, [*LTO_COMPILE, *PROFILE_GENERATE],
                                 ["-flto", *PROFILE_GENERATE_LINK])

    def _links(self, source: str, compile_args: list[str],
               link_args: list[str] | None) -> bool:
        """Whether a small C file with this source compiles with these flags without a
        warning, and (`link_args` not None) links into a shared library with those."""
        with tempfile.TemporaryDirectory() as scratch:
            probe = os.path.join(scratch, "probe.c")
            with open(probe, "w") as f:
                f.write(source + "int probe(int x) { return x + 1; }\n")
            try:
                objects = self.compiler.compile([probe], output_dir=scratch,
                                                extra_postargs=[*compile_args, "-Werror"])
                if link_args is not None:
                    self.compiler.link_shared_object(
                        objects, os.path.join(scratch, "probe.so"), extra_postargs=link_args)
            except (CompileError, LinkError):
                return False
        return True

    def _forget_counts(self) -> None:
        """Counts an earlier build left beside its objects (the counters add to them)."""
        for folder, _, names in os.walk(self.build_temp):
            for name in names:
                if name.endswith(".gcda"):
                    os.remove(os.path.join(folder, name))

    def _train(self) -> str | None:
        """The training run on the instrumented core (robox_train.py); what went wrong,
        or None."""
        import subprocess

        with tempfile.TemporaryDirectory() as work:
            try:
                done = subprocess.run([sys.executable, TRAINER, self.build_lib, work],
                                      stdin=subprocess.DEVNULL, capture_output=True,
                                      text=True, timeout=TRAINING_TIMEOUT_S)
            except (OSError, subprocess.TimeoutExpired) as error:
                return _reason(error)
        if done.returncode == 0:
            return None
        lines = (done.stderr or done.stdout).strip().splitlines()
        return _reason(RuntimeError(lines[-1] if lines else f"exit status {done.returncode}"))

    @staticmethod
    def _with_bodies(source: str, missing: set[str]) -> str:
        """The C file to compile for `source`: itself, or where it defines a function of
        C_BODIES a copy beside it with C_BODIES' bodies (written only when it changes, so
        an unchanged core is not compiled again). Signatures found leave `missing`."""
        if not source.endswith(".c"):
            return source
        with open(source, encoding="utf-8") as f:
            text = f.read()
        changed, absent = replace_bodies(text, C_BODIES)
        missing.intersection_update(absent)
        if changed == text:
            return source
        copy = source[:-2] + "-bodies.c"
        try:
            with open(copy, encoding="utf-8") as f:
                current = f.read()
        except OSError:
            current = None
        if current != changed:
            with open(copy, "w", encoding="utf-8") as f:
                f.write(changed)
        return copy

    def _takes(self, flag: str) -> bool:
        """Whether this build's compiler accepts `flag` without a warning."""
        return self.compiler.compiler_type == "unix" and self._links("", [flag], None)


def _cores() -> int:
    """The processors this build may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _compile_side_by_side(compiler, jobs: int) -> None:
    """Make `compiler` compile an extension's C files `jobs` at a time (the standard one
    compiles them one after another; each is a compiler process of its own, so threads
    only wait for them). Where its internals are not the standard ones, it is left as
    it is."""
    setup = getattr(compiler, "_setup_compile", None)
    cc_args = getattr(compiler, "_get_cc_args", None)
    one = getattr(compiler, "_compile", None)
    if jobs < 2 or setup is None or cc_args is None or one is None:
        return
    from concurrent.futures import ThreadPoolExecutor

    def compile(sources, output_dir=None, macros=None, include_dirs=None, debug=False,
                extra_preargs=None, extra_postargs=None, depends=None):
        macros, objects, extra_postargs, pp_opts, build = setup(
            output_dir, macros, include_dirs, sources, depends, extra_postargs)
        args = cc_args(pp_opts, debug, extra_preargs)
        todo = [(obj, *build[obj]) for obj in objects if obj in build]
        with ThreadPoolExecutor(jobs) as pool:
            for done in [pool.submit(one, obj, src, ext, args, extra_postargs, pp_opts)
                         for obj, src, ext in todo]:
                done.result()  # (the first failure is raised)
        return objects

    compiler.compile = compile


def compiler() -> str | None:
    """The C compiler a build would run (CC, as setuptools takes it), if it exists."""
    command = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    words = shlex.split(command)
    return shutil.which(words[0]) if words else None


@contextlib.contextmanager
def _kind(kind: str):
    """ROBOX_BUILD_KIND set to `kind` for the duration of a build step."""
    before = os.environ.get(BUILD)
    os.environ[BUILD] = kind
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(BUILD, None)
        else:
            os.environ[BUILD] = before


def get_requires_for_build_wheel(config_settings=None):
    with _kind("pure"):  # setuptools runs setup.py to list what it needs: without mypyc
        needed = list(_setuptools.get_requires_for_build_wheel(config_settings))
    choice = _choice()
    if choice == "1" or (choice == "auto" and compiler() is not None):
        needed += [MYPYC, *TRAINING]
    return needed


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    choice = _choice()
    if choice == "0":
        return _pure(wheel_directory, config_settings, metadata_directory)
    if choice == "auto" and compiler() is None:
        _say("no C compiler found (CC); building the pure-Python package (ROBOX_NATIVE=1 "
             "tries the compiled core all the same)")
        return _pure(wheel_directory, config_settings, metadata_directory)
    try:
        with _kind("native"):
            return _setuptools.build_wheel(wheel_directory, config_settings,
                                           metadata_directory)
    except (Exception, SystemExit) as error:
        if choice == "1":
            raise
        _say(f"the compiled core did not build ({_reason(error)}); building the pure-Python "
             "package")
        return _pure(wheel_directory, config_settings, metadata_directory)


def _reason(error: BaseException) -> str:
    """The last line of what went wrong, at most 200 characters (a failed compiler
    command names every flag)."""
    lines = str(error).strip().splitlines()
    text = lines[-1] if lines else type(error).__name__
    return text if len(text) <= 200 else text[:197] + "..."


def _pure(wheel_directory, config_settings, metadata_directory):
    with _kind("pure"):
        return _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)


def get_requires_for_build_editable(config_settings=None):
    with _kind("pure"):
        return _setuptools.get_requires_for_build_editable(config_settings)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    if _choice() == "1":
        _say(f"{CHOICE}=1 is ignored for an editable install (compiled modules would hide "
             "later edits of the sources); building pure Python")
    with _kind("pure"):
        return _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    with _kind("pure"):
        return _setuptools.prepare_metadata_for_build_wheel(metadata_directory, config_settings)


def prepare_metadata_for_build_editable(metadata_directory, config_settings=None):
    with _kind("pure"):
        return _setuptools.prepare_metadata_for_build_editable(metadata_directory,
                                                               config_settings)


def build_sdist(sdist_directory, config_settings=None):
    with _kind("pure"):
        return _setuptools.build_sdist(sdist_directory, config_settings)
