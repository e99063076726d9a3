"""The opt-in compiled core: what setup.py compiles is what robox.native reports on."""

import ast
import importlib
import os
import sys
from pathlib import Path

import pytest

from robox import native

ROOT = Path(__file__).resolve().parents[2]


def setup_modules() -> list[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and node.targets[0].id == "NATIVE_MODULES":
            return [p.removeprefix("src/").removesuffix(".py").replace("/", ".")
                    for p in ast.literal_eval(node.value)]
    raise AssertionError("setup.py has no NATIVE_MODULES")


def test_the_compiled_modules_are_the_ones_robox_native_knows():
    assert setup_modules() == list(native.MODULES)


@pytest.mark.parametrize("name", native.MODULES)
def test_each_module_reports_how_it_runs(name):
    module = importlib.import_module(name)
    assert (name in native.compiled_modules()) == (not module.__file__.endswith(".py"))


@pytest.mark.parametrize("name", native.MODULES)
def test_each_module_imports_first_in_a_fresh_interpreter(name):
    """A compiled module that reads another's class natively needs that class made
    first: one that imported it only for the type checker crashed the interpreter when
    it was the first of the package imported."""
    import subprocess

    run = subprocess.run([sys.executable, "-c", f"import {name}"], capture_output=True,
                         text=True, cwd=ROOT.parent)
    assert run.returncode == 0, run.stderr[-2000:]


def test_describe_counts_the_compiled_modules():
    n = len(native.compiled_modules())
    text = native.describe()
    whole = len(native.MODULES)
    assert (text == "pure Python") if n == 0 else text.startswith(f"compiled core ({n} of {whole}")


def test_the_build_backend_asks_for_mypyc_unless_it_cannot_or_must_not(monkeypatch,
                                                                         tmp_path):
    monkeypatch.syspath_prepend(str(ROOT / "buildsys"))
    sys.modules.pop("robox_build", None)
    backend = importlib.import_module("robox_build")
    seen = []
    monkeypatch.setattr(backend._setuptools, "get_requires_for_build_wheel",
                        lambda settings=None: seen.append(os.environ.get(backend.BUILD))
                        or ["wheel"])
    cc = tmp_path / "cc"
    cc.write_text("#!/bin/sh\n")
    cc.chmod(0o755)
    monkeypatch.setenv("CC", f"{cc} -pthread")  # a command line: its first word is run
    monkeypatch.delenv("ROBOX_NATIVE", raising=False)
    assert backend.get_requires_for_build_wheel() == ["wheel", backend.MYPYC,
                                                     *backend.TRAINING]
    monkeypatch.setenv("ROBOX_NATIVE", "0")
    assert backend.get_requires_for_build_wheel() == ["wheel"]
    monkeypatch.setenv("CC", str(tmp_path / "missing"))
    monkeypatch.setenv("ROBOX_NATIVE", "auto")
    assert backend.get_requires_for_build_wheel() == ["wheel"]  # no compiler: pure
    monkeypatch.setenv("ROBOX_NATIVE", "1")
    assert backend.get_requires_for_build_wheel() == ["wheel", backend.MYPYC,
                                                     *backend.TRAINING]  # required
    # setup.py is run without mypyc while the requirements are listed, and that leaves
    # nothing behind in the environment
    assert seen == ["pure"] * 4 and backend.BUILD not in os.environ


def _square_edges() -> list[int]:
    """Whole numbers on both sides of squares, where a rounded square root would go wrong,
    up to the 2**32 the interrupt's radicands stay below and on to 2**53."""
    out = [0, 1, 2, 3]
    roots = [*range(2, 70_000, 3), 2**26 - 1, 2**26, 2**26 + 1, 94_906_265, 94_906_266]
    for k in roots:
        out += [k * k - 1, k * k, k * k + 1]
    return [x for x in out if x < 2**53]


def test_the_native_square_root_is_math_isqrt():
    """carith.isqrt32's own body (in native integers when compiled; interpreted, the name
    is math.isqrt itself) gives math.isqrt's answer on every square's edge."""
    import math

    from robox.firmware.carith import isqrt32, native_isqrt32

    edges = _square_edges()
    assert [native_isqrt32(x) for x in edges] == [math.isqrt(x) for x in edges]
    assert [isqrt32(x) for x in edges[:1000]] == [math.isqrt(x) for x in edges[:1000]]


def _float_cases() -> list[float]:
    """Doubles around the float grid: the float32 values of a seeded sample and the points
    half a float-step either side (ties), a hair inside and outside them, each power of
    two's neighbours, the normal range's ends, the overflow edge, zeros, infinities, NaN."""
    import math
    import random

    from robox.firmware.carith import struct_f32

    rng = random.Random(1913)
    out = [0.0, -0.0, math.inf, -math.inf, math.nan, 1e-45, 7e-46, 1.1754942e-38,
           3.4028234663852886e38, 3.4028235677973366e38, 3.402823567797336e38]
    for _ in range(20_000):
        out.append(rng.uniform(-1.0, 1.0) * 2.0 ** rng.randint(-160, 140))
        f = struct_f32(rng.uniform(-1e6, 1e6))
        half = 2.0 ** (math.frexp(f)[1] - 25)
        out += [f, f + half, f - half, f + half * (1 + 2**-20), f - half * (1 - 2**-20)]
    for k in range(-150, 130):
        b = 2.0**k
        out += [b, -b, b * (1 - 2**-25), b * (1 + 2**-24), b * (1 - 2**-24), b * (1 - 2**-26)]
    return out


def test_the_native_float_rounding_is_the_struct_modules():
    """carith.f32's own body (compiled, the C conversion the build gives it; interpreted,
    the double arithmetic its Python spells out, though the name f32 is struct_f32 there)
    rounds every case as struct's "<f" conversion does, sign and all."""
    import math

    from robox.firmware.carith import native_f32, struct_f32

    def key(v: float) -> tuple:
        return ("nan",) if v != v else (v, math.copysign(1.0, v))

    cases = _float_cases()
    assert [key(native_f32(v)) for v in cases] == [key(struct_f32(v)) for v in cases]


def test_packed_vectors_are_librts_where_compiled_and_lists_otherwise():
    """robox.packed tells the two builds apart at run time; the firmware's per-axis
    numbers are librt's packed vectors only where its modules run compiled."""
    from robox import packed
    from robox.firmware.carith import i64

    compiled = "robox.packed" in native.compiled_modules()
    assert compiled == packed.COMPILED
    floats = packed.vec[float]([0.5, -0.0, 1e300, float("inf")])
    ints = packed.append(packed.vec[i64]([1, -(2**40)]), 7)
    assert [float(x) for x in floats] == [0.5, -0.0, 1e300, float("inf")]
    assert str(floats[1]) == "-0.0"  # a zero's sign is kept
    assert [int(x) for x in ints] == [1, -(2**40), 7]
    floats[2] = 2.25  # written in place, as the firmware's arrays are
    assert floats[2] == 2.25
    if compiled:
        assert type(floats).__name__ == "vec[float]" and type(ints).__name__ == "vec[i64]"
    else:
        assert type(floats) is list and type(ints) is list


def test_a_vector_of_floats_goes_to_little_endian_doubles_and_back():
    """floats_to_bytes writes each float as struct's "<d" does, on either build, and
    floats_from_bytes reads those bytes back bit for bit (a zero's sign, infinities, a
    NaN's payload, the least subnormal); an empty vector is no bytes."""
    import struct

    from robox import packed

    values = [0.5, -0.0, 1e300, float("inf"), -float("inf"), 5e-324, -1.0 / 3.0,
              struct.unpack("<d", bytes.fromhex("0100000000f8ff7f"))[0], 123456789.125]
    data = packed.floats_to_bytes(packed.vec[float](values))
    assert data == struct.pack(f"<{len(values)}d", *values)
    back = packed.floats_from_bytes(data)
    assert len(back) == len(values)
    assert [struct.pack("<d", float(x)) for x in back] == \
        [struct.pack("<d", v) for v in values]
    assert packed.floats_to_bytes(packed.vec[float]()) == b""
    assert len(packed.floats_from_bytes(b"")) == 0


def _core_library() -> Path | None:
    """The compiled core's shared library (the one that holds every module's functions),
    where the install has one."""
    import robox.firmware.carith as carith

    if carith.__file__.endswith(".py"):
        return None
    site = Path(carith.__file__).resolve().parents[2]  # robox/firmware/carith.*
    found = [p for p in site.glob("*__mypyc*") if p.suffix in (".so", ".pyd", ".dylib")]
    return found[0] if len(found) == 1 else None


@pytest.mark.skipif(_core_library() is None or sys.platform != "linux",
                    reason="a compiled install's core library, loaded as ELF")
def test_the_compiled_cores_functions_call_each_other_directly():
    """setup.py's SPEED_FLAGS reached the build: the core's functions are not exported
    (none can be replaced at load time, so the compiler called them directly and
    inlined the small ones), while each module's PyInit_ function still is."""
    import ctypes

    library = ctypes.CDLL(str(_core_library()))
    with pytest.raises(AttributeError):
        library.CPyDef_carith___f32  # noqa: B018 (the lookup is the test)
    shim = importlib.import_module("robox.firmware.carith").__file__
    assert ctypes.CDLL(shim).PyInit_carith


def test_the_build_keeps_only_the_flags_its_compiler_takes(monkeypatch):
    """BuildExt asks this machine's C compiler: a flag it rejects or warns of is left
    out; on Linux (GCC or Clang) every one of SPEED_FLAGS is taken."""
    from setuptools import Distribution
    from setuptools._distutils.ccompiler import new_compiler
    from setuptools._distutils.sysconfig import customize_compiler

    monkeypatch.syspath_prepend(str(ROOT / "buildsys"))
    backend = importlib.import_module("robox_build")
    if backend.compiler() is None:
        pytest.skip("no C compiler")
    command = backend.BuildExt(Distribution())
    command.compiler = new_compiler()
    customize_compiler(command.compiler)
    assert command._takes("-O2")
    assert not command._takes("-fno-such-option-robox")
    if sys.platform == "linux":
        assert [f for f in backend.SPEED_FLAGS if command._takes(f)] == backend.SPEED_FLAGS


# C shaped as mypyc writes a module's functions: carith.f32's definition (its real
# signature; a body that only hands back its argument, unrounded) and one whose name
# begins with f32's
_MYPYC_SHAPED = """\
/* the functions of a compiled module, as mypyc writes them */

double CPyDef_carith___f32(double cpy_r_value) {
    char cpy_r_r0;
    cpy_r_r0 = cpy_r_value == 0.0;
    if (!cpy_r_r0) goto CPyL2;
    return cpy_r_value;
CPyL2: ;
    return cpy_r_value;
}

double CPyDef_carith___f32_accumulate(double cpy_r_x, double cpy_r_step) {
    return cpy_r_x + cpy_r_step;
}
"""


def test_the_build_gives_f32_cs_own_conversion_and_it_rounds_as_struct(tmp_path,
                                                                       monkeypatch):
    """BuildExt compiles a copy of mypyc's C in which carith.f32's body is C's float
    conversion; compiled here, that body rounds every case as struct's "<f" does, the
    function whose name begins the same is left as it was, and an unchanged copy is not
    written again (so an unchanged core is not compiled again)."""
    import ctypes
    import math

    from setuptools._distutils.ccompiler import new_compiler
    from setuptools._distutils.sysconfig import customize_compiler

    from robox.firmware.carith import struct_f32

    monkeypatch.syspath_prepend(str(ROOT / "buildsys"))
    backend = importlib.import_module("robox_build")
    if backend.compiler() is None:
        pytest.skip("no C compiler")
    source = tmp_path / "__native_core.c"
    source.write_text(_MYPYC_SHAPED)
    missing = set(backend.C_BODIES)
    copy = backend.BuildExt._with_bodies(str(source), missing)
    assert copy != str(source) and not missing
    assert source.read_text() == _MYPYC_SHAPED  # mypyc's own file is left alone
    text = Path(copy).read_text()
    assert "double CPyDef_carith___f32(double cpy_r_value) {\n" \
           "    return (double)(float)cpy_r_value;\n}\n" in text
    assert text.endswith(_MYPYC_SHAPED[_MYPYC_SHAPED.index("\ndouble CPyDef_carith___f32_"):])
    written = os.stat(copy).st_mtime_ns
    os.utime(copy, ns=(written - 10**9, written - 10**9))
    assert backend.BuildExt._with_bodies(str(source), set()) == copy
    assert os.stat(copy).st_mtime_ns == written - 10**9

    plain = tmp_path / "plain.c"
    plain.write_text("int probe(void) { return 0; }\n")
    still = set(backend.C_BODIES)
    assert backend.BuildExt._with_bodies(str(plain), still) == str(plain)
    assert still == set(backend.C_BODIES)

    compiler = new_compiler()
    customize_compiler(compiler)
    objects = compiler.compile([copy], output_dir=str(tmp_path), extra_postargs=["-fPIC"])
    library = tmp_path / "f32.so"
    compiler.link_shared_object(objects, str(library))
    f32 = ctypes.CDLL(str(library)).CPyDef_carith___f32
    f32.restype, f32.argtypes = ctypes.c_double, [ctypes.c_double]

    def key(v: float) -> tuple:
        return ("nan",) if v != v else (v, math.copysign(1.0, v))

    cases = _float_cases()
    assert [key(f32(v)) for v in cases] == [key(struct_f32(v)) for v in cases]


@pytest.mark.parametrize(("record", "said"), [
    ('{"link_time": true, "profile": true}',
     "optimised at link time and from a training run's profile"),
    ('{"link_time": true, "profile": false}', "optimised at link time"),
    ('{"link_time": false, "profile": false}', "compiled file by file"),
    ('{"link_time": 1, "profile": "yes"}', "compiled file by file"),  # only true is true
    ('["link_time"]', None),
    ("{not json", None),
    (None, None),  # no record: a pure build's package
])
def test_the_build_record_says_how_the_core_was_optimised(tmp_path, record, said):
    path = tmp_path / "native_build.json"
    if record is not None:
        path.write_text(record)
    assert native.optimisation(str(path)) == said
