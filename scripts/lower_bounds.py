"""The oldest versions pyproject.toml allows, installed and tested (docs/development.md, "Dependency ranges").

Each runtime dependency's lower bound ``name>=X`` becomes the pin ``name==X.*`` (the lowest release series the
range allows, e.g. ``numpy==1.26.*``); ranges with an upper bound pin the same way (``open3d==0.20.*``). torch is
the exception (``EXEMPT``): this command installs the CPU wheel ``torch==2.13.0`` as scripts/test.sh does.

    python scripts/lower_bounds.py --pins            # print the pins
    python scripts/lower_bounds.py VENV_DIR          # make a venv there, install the pins, run LOWER_BOUND_TESTS

A run that passes shows that every lower bound but torch's is a tested one; tests/test_architecture.py checks
that every dependency of pyproject.toml has a lower bound and is pinned or exempt here.
"""
from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

EXEMPT = {
    "torch": "the CPU wheel torch==2.13.0 is installed as scripts/test.sh does: older torch CPU wheels are not on "
             "the package index this project's CI reads, and a default older wheel pulls GBs of CUDA. The bound "
             "(>=2.0) is the API datagen uses (torch.aminmax, binomial, poisson, Generator, DataLoader).",
}
"""Dependencies whose lower bound is documented, not installed, with the reason."""

LOWER_BOUND_TESTS = ["tests/test_transport.py", "tests/test_area.py", "tests/test_multibounce.py",
                     "tests/test_spad.py", "tests/test_torch_noise.py", "tests/test_loader.py", "tests/test_dataset.py",
                     "tests/test_capture_io.py", "tests/test_tal.py", "tests/test_planner.py", "tests/test_cli.py"]
"""Tests run at the lower bounds: every stage, from scene loading to the torch loader, zarr stores and HDF5 files."""


def dependencies() -> list[str]:
    """The runtime requirement strings of pyproject.toml, as written."""
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]


def lower_bound(requirement: str) -> tuple[str, str | None]:
    """(name with extras, the version after ``>=``, None when the requirement has no lower bound)."""
    name = re.match(r"[A-Za-z0-9_.\-]+(\[[^\]]*\])?", requirement).group(0)
    found = re.search(r">=\s*([0-9][0-9A-Za-z.]*)", requirement)
    return name, found.group(1) if found else None


def pins() -> list[str]:
    """``name==X.*`` for every dependency with a lower bound X that is not in ``EXEMPT``."""
    out = []
    for requirement in dependencies():
        name, floor = lower_bound(requirement)
        if floor is not None and re.sub(r"\[.*", "", name) not in EXEMPT:
            out.append(f"{name}=={floor}.*")
    return out


def main(argv: list[str]) -> int:
    if argv == ["--pins"]:
        print("\n".join(pins()))
        return 0
    if len(argv) != 1:
        print(__doc__)
        return 2
    venv = Path(argv[0]).resolve()
    python = venv / "bin" / "python"

    def run(*args: str) -> None:
        print("+", " ".join(args), flush=True)
        subprocess.run(args, check=True, cwd=ROOT)

    run(sys.executable, "-m", "venv", str(venv))
    pip = (str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--only-binary=:all:")
    constraints = venv / "lower-bounds.txt"
    constraints.write_text("".join(re.sub(r"\[.*\]", "", pin) + "\n" for pin in pins()))   # constraints take no extras
    run(*pip, "torch==2.13.0")
    run(*pip, "-e", ".[test]", "--constraint", str(constraints))      # every pinned dependency at its floor series
    run(str(python), "-m", "pip", "freeze", "--exclude-editable")
    run(str(python), "-m", "pytest", "-q", "-n", "auto", "--dist", "loadfile", "-p", "no:cacheprovider",
        *LOWER_BOUND_TESTS)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
