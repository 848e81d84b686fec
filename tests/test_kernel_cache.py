"""The kernel cache is found by the content of the kernel sources, not by their time stamps (hydraulics.kernel_cache).

Nothing is compiled here: the tests hash copies of the kernel sources, write and read the build record, and start
interpreters that import ``hydraulics`` (which chooses numba's cache folder and CPU target) without compiling.
"""

import ast
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from conftest import ROOT
from hydraulics import kernel_cache as kc

CHAIN = kc.Toolchain(python="cpython-3.11.7", numba="0.68.1", llvmlite="0.50.0", numpy="2.4.6", cpu="generic",
                     features="", platform="linux-x86_64")


def copy_sources(target: Path) -> list[str]:
    """The kernel sources copied to ``target`` (same relative paths); their paths there."""
    for path in kc.source_files(str(ROOT)):
        relative = Path(path).relative_to(ROOT)
        (target / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, target / relative)
    return kc.source_files(str(target))


def test_the_key_follows_the_sources_content_and_toolchain_and_ignores_time_stamps(tmp_path):
    files = copy_sources(tmp_path)
    assert len(files) == len(kc.source_files(str(ROOT))) > 20
    key = kc.cache_key(files, str(tmp_path), CHAIN)
    assert re.fullmatch(r"[0-9a-f]{20}", key)
    # another folder with the same content (a clone elsewhere, another machine): the same key
    assert kc.cache_key(kc.source_files(str(ROOT)), str(ROOT), CHAIN) == key
    # every file touched, as a fresh clone or a checkout does: the same key
    for path in files:
        os.utime(path, ns=(1_000_000_000, 1_000_000_000))
    assert kc.cache_key(files, str(tmp_path), CHAIN) == key
    # one byte of one law changed: another key; restored: the first key again
    law = tmp_path / "hydraulics" / "components" / "orifice.py"
    text = law.read_bytes()
    law.write_bytes(text.replace(b"def ", b"def  ", 1))
    changed = kc.cache_key(files, str(tmp_path), CHAIN)
    assert changed != key
    law.write_bytes(text)
    assert kc.cache_key(files, str(tmp_path), CHAIN) == key
    # a module whose constants the kernels compile in (not itself a kernel file) counts too
    numerics = tmp_path / "hydraulics" / "numerics.py"
    numerics.write_text(numerics.read_text() + "\n")
    assert kc.cache_key(files, str(tmp_path), CHAIN) not in (key, changed)
    numerics.write_bytes((ROOT / "hydraulics" / "numerics.py").read_bytes())
    # another CPU target, numba, llvmlite or Python: another key
    for field, value in (("cpu", "skylake"), ("features", "+avx2"), ("numba", "0.69.0"), ("llvmlite", "0.51.0"),
                         ("python", "cpython-3.12.0"), ("platform", "linux-aarch64")):
        assert kc.cache_key(files, str(tmp_path), replace(CHAIN, **{field: value})) != key, field


def test_the_build_record_fits_only_the_stamps_it_was_built_for(tmp_path):
    """``hydroplant compile`` skips its work only while numba would load every kernel: the record's groups cover the
    request and no kernel file was touched since (numba checks each file's time stamp and size)."""
    files = copy_sources(tmp_path / "src")
    root = str(tmp_path / "src")
    folder = tmp_path / "cache"
    folder.mkdir()
    cache = kc.KernelCache(folder=str(folder), key=kc.cache_key(files, root, CHAIN), keyed=True, toolchain=CHAIN)
    assert not kc.fits(cache, ["mujoco"], root)  # nothing built yet
    kc.write_manifest(cache, ["mujoco", "pbd"], root)
    assert kc.fits(cache, ["mujoco"], root) and kc.fits(cache, ["pbd", "mujoco"], root)
    assert not kc.fits(cache, ["xpbd"], root)  # a group not built
    kc.write_manifest(cache, ["xpbd"], root)  # a later build of another group adds to the record
    assert kc.fits(cache, ["mujoco", "pbd", "xpbd"], root)
    assert not kc.fits(replace(cache, key="0" * 20), ["mujoco"], root)  # the record of other sources
    os.utime(files[3], ns=(2_000_000_000, 2_000_000_000))  # touched: numba would recompile that file's kernels
    assert not kc.fits(cache, ["mujoco"], root)
    assert "time stamps differ" in kc.describe(cache)
    record = json.loads((folder / kc.MANIFEST).read_text())
    assert record["toolchain"]["cpu"] == "generic" and set(record["stamps"]) == {
        str(Path(f).relative_to(root).as_posix()) for f in files}


def _module_file(name: str) -> Path | None:
    path = ROOT / (name.replace(".", "/") + ".py")
    if path.is_file():
        return path
    path = ROOT / name.replace(".", "/") / "__init__.py"
    return path if path.is_file() else None


def test_the_sources_cover_every_compiled_module_and_what_it_imports():
    """numba compiles a kernel's callees and the globals it reads, constants imported from other modules included:
    every module defining a compiled function, and every package module it imports, is part of the key."""
    compiled = re.compile(r"@(njit|kernel|jit|inline|intrinsic|numba\.)|njit\(|cfunc\(|_jit import")
    modules = [p for p in sorted(ROOT.glob("hydraulics/**/*.py")) + sorted(ROOT.glob("sim/**/*.py"))
               if compiled.search(p.read_text())]
    assert {"hydraulics/_compiled.py", "sim/plants/mujoco_fast.py", "sim/xpbd/compiled.py"} <= {
        p.relative_to(ROOT).as_posix() for p in modules}
    needed = set(modules)
    for path in modules:
        package = path.relative_to(ROOT).with_suffix("").parts[:-1]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = list(package[:len(package) - node.level + 1]) if node.level else []
                module = ".".join(base + ([node.module] if node.module else []))
                names = [module] + [f"{module}.{alias.name}" for alias in node.names]
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            else:
                continue
            needed.update(f for f in map(_module_file, names) if f is not None and f.parts[len(ROOT.parts)] in
                          ("hydraulics", "sim"))
    listed = {Path(p) for p in kc.source_files(str(ROOT))}
    assert not needed - listed, sorted(str(p.relative_to(ROOT)) for p in needed - listed)


PROBE = """
import json, os, sys
import hydraulics
from hydraulics import kernel_cache
state = kernel_cache.CURRENT
numba_config = None
if sys.argv[1] == "numba":
    import numba
    numba_config = [numba.config.CACHE_DIR, numba.config.CPU_NAME, numba.config.CPU_FEATURES]
print(json.dumps({"folder": state.folder, "key": state.key, "keyed": state.keyed, "cpu": state.cpu,
                  "env": [os.environ.get("NUMBA_CACHE_DIR"), os.environ.get("NUMBA_CPU_NAME")],
                  "numba": numba_config, "prefix": sys.prefix, "base": sys.base_prefix}))
"""


def probe(env: dict, numba: bool = False) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_CPU_NAME",
                                                            "NUMBA_CPU_FEATURES")} | env
    done = subprocess.run([sys.executable, "-c", PROBE, "numba" if numba else "-"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_importing_the_package_chooses_the_keyed_folder_and_a_generic_cpu_before_numba(tmp_path):
    out = probe({}, numba=True)
    assert out["keyed"] and out["cpu"] == "generic"
    assert Path(out["folder"]).name == kc.PREFIX + out["key"]
    if out["prefix"] != out["base"]:  # in a virtual environment: the cache lives inside it
        assert Path(out["folder"]).parent == Path(out["prefix"]) / "var" / "cache" / "hydroplant"
    assert out["env"] == [out["folder"], "generic"]
    assert out["numba"] == [out["folder"], "generic", ""]  # numba read them: generic CPU, no host features
    # the user's own choices stand: their folder as is, their CPU in the key
    mine = probe({"NUMBA_CACHE_DIR": str(tmp_path), "NUMBA_CPU_NAME": "znver2"})
    assert mine["folder"] == str(tmp_path) and not mine["keyed"] and mine["cpu"] == "znver2"
    assert mine["key"] != out["key"]
    # a child process inherits the keyed folder and finds it keyed again
    child = probe({"NUMBA_CACHE_DIR": out["folder"], "NUMBA_CPU_NAME": "generic"})
    assert child["keyed"] and child["folder"] == out["folder"]


def test_numba_imported_first_keeps_its_own_settings():
    """A program that imported numba before hydroplant keeps numba's settings (its host CPU and default cache)."""
    code = ("import os, json, numba\nfrom hydraulics import kernel_cache\ns = kernel_cache.CURRENT\n"
            "print(json.dumps([s.keyed, s.cpu, os.environ.get('NUMBA_CPU_NAME'), numba.config.CPU_NAME]))")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "NUMBA_CPU_NAME")}
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == [False, "host", None, None]


def test_compile_names_only_its_own_earlier_builds_as_superseded(tmp_path):
    """``hydroplant compile`` removes the folders it built for earlier sources of this same installation; folders of
    other installations or interpreters, and folders it did not build, stay."""
    root = str(tmp_path / "src")
    made = {}
    for name, record_root, python in (("current", root, sys.executable), ("older", root, sys.executable),
                                      ("other-checkout", str(tmp_path / "elsewhere"), sys.executable),
                                      ("other-python", root, "/opt/python3.13/bin/python3"), ("unrecorded", None, None)):
        folder = tmp_path / "caches" / (kc.PREFIX + name)
        folder.mkdir(parents=True)
        if record_root is not None:
            (folder / kc.MANIFEST).write_text(json.dumps({"key": name, "root": record_root, "python": python}))
        made[name] = str(folder)
    (tmp_path / "caches" / "not-a-kernel-cache").mkdir()
    cache = kc.KernelCache(folder=made["current"], key="current", keyed=True, toolchain=CHAIN)
    assert kc.superseded(cache, root) == [made["older"]]
    assert kc.superseded(replace(cache, keyed=False), root) == []  # a folder the user named: never pruned
