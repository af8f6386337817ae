"""Packaging contracts: recon without Mitsuba, LLVM resolution, CLI basics."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _py(code: str, **env):
    import os

    e = dict(os.environ)
    e.update(env)
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=e, capture_output=True, text=True, timeout=300)


def test_recon_imports_without_mitsuba():
    r = _py("import recon, recon.io, spad_detector.coates, sys; assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules")
    assert r.returncode == 0, r.stderr


def test_llvm_is_resolved_to_17_or_newer():
    r = _py("import transient_mi, drjit as dr; print(dr.detail.llvm_version()[0])")
    assert r.returncode == 0, r.stderr
    assert int(r.stdout.strip().splitlines()[-1]) >= 17


def test_user_llvm_too_old_gives_clear_error(tmp_path):
    bogus = tmp_path / "libLLVM.so"
    bogus.write_bytes(b"not a library")
    r = _py("import transient_mi", DRJIT_LIBLLVM_PATH=str(bogus))
    assert r.returncode != 0
    assert "DRJIT_LIBLLVM_PATH" in r.stderr and "LLVM >= 17" in r.stderr


def test_unknown_variant_env_gives_clear_error():
    r = _py("import transient_mi", TRANSIENT_MI_VARIANT="llvm_ad_nonsense")
    assert r.returncode != 0
    assert "variant='llvm_ad_nonsense'" in r.stderr and "llvm_ad_mono" in r.stderr
