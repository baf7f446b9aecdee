"""Which of armvision's dependencies install from a wheel on a platform, and what setup needs.

Two uses, both asking pip itself (its finder, its tag rules) rather than guessing:

    python scripts/resolve_platform.py [--python 3.10,3.11,3.12,3.13] [--glibc 2.35]
        The table (`make check-wheels`): every runtime and optional dependency in pyproject.toml,
        and everything they pull in, resolved for linux/aarch64 one package at a time (so one
        missing hides no other) with `pip install --dry-run --no-deps --only-binary=:all:
        --platform manylinux_2_*_aarch64 --python-version X --report -`, the resolution
        `pip download` does without fetching the files. A package without a wheel is looked up
        on the index: source only (pure Python, or compiled: needs a compiler) or missing.

    python scripts/resolve_platform.py --here --extras dev,realsense --optional realsense
        `make setup`: resolves the extras for this interpreter and machine; an optional extra
        whose packages cannot be installed here is dropped with a message, and if a package
        must be compiled from source the Debian packages to build it are installed first
        (scripts/system-packages.sh). Prints the extras to install, e.g. `dev,realsense`.

Runs with nothing but the standard library and pip (a fresh venv), Python >= 3.10.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import sysconfig
import tempfile
import urllib.request
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

try:
    from packaging.markers import Marker
    from packaging.requirements import Requirement
    from packaging.specifiers import SpecifierSet
    from packaging.utils import canonicalize_name, parse_sdist_filename, parse_wheel_filename
    from packaging.version import InvalidVersion, Version
except ImportError:  # a fresh venv has only pip, which carries its own copy
    from pip._vendor.packaging.markers import Marker
    from pip._vendor.packaging.requirements import Requirement
    from pip._vendor.packaging.specifiers import SpecifierSet
    from pip._vendor.packaging.utils import (
        canonicalize_name,
        parse_sdist_filename,
        parse_wheel_filename,
    )
    from pip._vendor.packaging.version import InvalidVersion, Version

if sys.version_info >= (3, 11):
    import tomllib
else:
    try:
        import tomli as tomllib
    except ImportError:
        from pip._vendor import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
PYPI = "https://pypi.org/simple"

WHEEL = "wheel"
SDIST_PURE = "sdist-only (pure Python)"
SDIST_COMPILED = "sdist-only (compiled)"
MISSING = "missing"
NOT_NEEDED = "not needed"


@dataclass(frozen=True)
class Target:
    """A CPython version on Linux for one machine and glibc (the manylinux tags it accepts)."""

    python: str  # "3.10"
    machine: str = "aarch64"
    glibc: tuple[int, int] = (2, 35)  # Ubuntu 22.04 (JetPack 6); JetPack 5's 20.04 has 2.31
    here: bool = False  # this interpreter and machine: pip's own tags, no --platform

    def pip_args(self) -> list[str]:
        """pip's --platform/--python-version/--abi for this target (nothing for ``here``).

        pip matches a `manylinux_2_Y` platform exactly, so every glibc from 2.17 up to the
        target's is passed (2.17 is manylinux2014, the oldest aarch64 wheels use)."""
        if self.here:
            return []
        major, minor = self.glibc
        args: list[str] = []
        for y in range(17, minor + 1):
            args += ["--platform", f"manylinux_{major}_{y}_{self.machine}"]
        args += ["--platform", f"manylinux2014_{self.machine}"]
        nodot = self.python.replace(".", "")
        args += ["--python-version", self.python, "--implementation", "cp", "--abi", f"cp{nodot}"]
        return args

    def marker_env(self) -> dict[str, str]:
        """The PEP 508 environment requirement markers are evaluated in."""
        if self.here:
            from platform import machine

            env = {"platform_machine": machine()}
        else:
            env = {"platform_machine": self.machine}
        return env | {
            "python_version": self.python,
            "python_full_version": f"{self.python}.0",
            "sys_platform": "linux",
            "platform_system": "Linux",
            "os_name": "posix",
            "implementation_name": "cpython",
            "platform_python_implementation": "CPython",
            "extra": "",
        }

    def describe(self) -> str:
        if self.here:
            from platform import machine

            return f"Linux {machine()}, Python {self.python}"
        return f"Linux {self.machine} (glibc {self.glibc[0]}.{self.glibc[1]}), Python {self.python}"


@dataclass(frozen=True)
class Need:
    """One requirement and who asked for it ("runtime", an extra's name, or a package)."""

    requirement: str
    needed_by: tuple[str, ...]

    @property
    def name(self) -> str:
        return canonicalize_name(Requirement(self.requirement).name)


@dataclass(frozen=True)
class Result:
    """How one requirement installs on one target."""

    status: str  # WHEEL, SDIST_PURE, SDIST_COMPILED, MISSING or NOT_NEEDED
    version: str | None = None
    filename: str | None = None
    requires: tuple[str, ...] = ()  # the wheel's Requires-Dist, for the closure

    def cell(self) -> str:
        if self.status == NOT_NEEDED:
            return "-"
        if self.status == MISSING:
            return "**missing**"
        label = "wheel" if self.status == WHEEL else f"**{self.status}**"
        return f"{label} {self.version}" if self.version else label


@dataclass
class Row:
    need: Need
    results: dict[str, Result] = field(default_factory=dict)  # python version -> result
    needed_by: dict[str, None] = field(default_factory=dict)  # an ordered set of askers


# --- requirements -----------------------------------------------------------------------------


def project_needs(pyproject: Path, extras: Iterable[str] | None = None) -> list[Need]:
    """The runtime requirements and those of ``extras`` (every extra if None), one per package,
    in pyproject order; a package listed twice (dev repeats some extras) names both askers."""
    project = tomllib.loads(pyproject.read_text())["project"]
    optional: dict[str, list[str]] = project.get("optional-dependencies", {})
    groups = [("runtime", project.get("dependencies", []))]
    chosen = list(optional) if extras is None else list(extras)
    for extra in chosen:
        if extra not in optional:
            raise SystemExit(f"resolve_platform: no extra {extra!r} in {pyproject}")
        groups.append((extra, optional[extra]))
    needs: dict[str, Need] = {}
    for origin, requirements in groups:
        for text in requirements:
            name = canonicalize_name(Requirement(text).name)
            if name in needs:
                old = needs[name]
                needs[name] = Need(old.requirement, (*old.needed_by, origin))
            else:
                needs[name] = Need(text, (origin,))
    return list(needs.values())


def applies(requirement: str, target: Target) -> bool:
    """Does the requirement's environment marker select it on the target?"""
    marker = Requirement(requirement).marker
    return marker is None or marker.evaluate(target.marker_env())


def dependencies(requires_dist: Iterable[str], target: Target) -> list[str]:
    """A wheel's Requires-Dist that the target installs (no extras asked for, markers true)."""
    env = target.marker_env()
    chosen = []
    for text in requires_dist:
        marker = Requirement(text).marker
        if marker is None or Marker(str(marker)).evaluate(env):
            chosen.append(text)
    return chosen


# --- pip and the index ------------------------------------------------------------------------


def pip_env() -> dict[str, str]:
    """pip's environment without this machine's own indexes, wheel folders and constraints, so
    the answer is PyPI's (the index a Jetson sees), not a local cache's."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
    env["PIP_CONFIG_FILE"] = os.devnull
    for keep in ("PIP_CERT", "PIP_DEFAULT_TIMEOUT"):
        if keep in os.environ:
            env[keep] = os.environ[keep]
    return env


def without_marker(requirement: str) -> str:
    """The requirement without its marker: pip evaluates markers for the Python running it, not
    for --python-version, so they are evaluated here (``applies``) instead."""
    req = Requirement(requirement)
    req.marker = None
    return str(req)


def pip_report_command(requirement: str, target: Target, index: str) -> list[str]:
    """One requirement's dry-run resolution: wheels only, no dependencies, a JSON report."""
    with_target = [] if target.here else ["--target", tempfile.gettempdir() + "/resolve-platform"]
    return [
        sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed",
        "--no-deps", "--only-binary=:all:", "--quiet", "--report", "-",
        "--index-url", index, *with_target, *target.pip_args(), without_marker(requirement),
    ]  # fmt: skip


def parse_report(report_json: str) -> Result:
    """The wheel pip would install, from its ``--report`` (one package, ``--no-deps``)."""
    report = json.loads(report_json)
    (item,) = report["install"]
    url = item["download_info"]["url"]
    metadata = item["metadata"]
    return Result(
        WHEEL,
        version=metadata["version"],
        filename=url.rsplit("/", 1)[-1],
        requires=tuple(metadata.get("requires_dist") or ()),
    )


def run_pip(command: Sequence[str]) -> tuple[int, str, str]:
    done = subprocess.run(command, capture_output=True, text=True, env=pip_env())
    return done.returncode, done.stdout, done.stderr


def fetch_index(name: str, index: str) -> dict:
    """The project's page on a PEP 691 (JSON) simple index."""
    request = urllib.request.Request(
        f"{index.rstrip('/')}/{name}/", headers={"Accept": "application/vnd.pypi.simple.v1+json"}
    )
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return json.load(response)
    except urllib.error.HTTPError as exc:
        if exc.code == 404:
            return {"files": []}
        raise


def classify_without_wheel(requirement: str, python: str, index_page: dict) -> Result:
    """No wheel fits: is there a source distribution pip would build, and does it compile?

    The newest sdist whose version the requirement allows, not yanked, whose Requires-Python
    admits ``python``. It is taken to be compiled if the project publishes any wheel for a
    specific platform (not ``-any``), e.g. pupil-apriltags' x86_64 wheels; otherwise pure Python,
    which pip builds with no compiler (filterpy, modern-robotics' older releases)."""
    req = Requirement(requirement)
    best: Version | None = None
    for entry in index_page.get("files", []):
        filename = entry["filename"]
        if filename.endswith(".whl") or entry.get("yanked"):
            continue
        try:
            version = parse_sdist_filename(filename)[1]
        except (ValueError, InvalidVersion):
            continue  # .exe, .egg and other old formats pip ignores
        if not req.specifier.contains(version, prereleases=False):
            continue
        requires_python = entry.get("requires-python")
        if requires_python and not SpecifierSet(requires_python).contains(python):
            continue
        if best is None or version > best:
            best = version
    if best is None:
        return Result(MISSING)
    status = SDIST_COMPILED if project_compiles(index_page) else SDIST_PURE
    return Result(status, version=str(best))


def resolve_one(requirement: str, target: Target, index: str) -> Result:
    if not applies(requirement, target):
        return Result(NOT_NEEDED)
    code, out, err = run_pip(pip_report_command(requirement, target, index))
    if code == 0:
        return parse_report(out)
    if "No matching distribution found" not in err:  # the network, not the package
        lines = err.strip().splitlines() or [f"exit status {code}"]
        raise SystemExit(f"resolve_platform: pip failed on {requirement!r}: {lines[-1]}")
    name = canonicalize_name(Requirement(requirement).name)
    return classify_without_wheel(requirement, target.python, fetch_index(name, index))


# --- the table --------------------------------------------------------------------------------


def resolve_closure(
    needs: list[Need],
    targets: list[Target],
    resolve: Callable[[str, Target], Result],
    jobs: int = 4,
) -> list[Row]:
    """Every need on every target, then, on each target, what its wheels there require, until
    nothing new appears; a package no wheel requires on a target is NOT_NEEDED there.

    A dependency reached from several packages on one target is resolved once, with the first
    requirement text seen (its version range then comes from that package)."""
    rows: dict[str, Row] = {}
    queue = [(need, target) for need in needs for target in targets]
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        while queue:
            work: list[tuple[Need, Target]] = []
            for need, target in queue:
                row = rows.setdefault(need.name, Row(need))
                row.needed_by.update(dict.fromkeys(need.needed_by))
                if target.python not in row.results:
                    row.results[target.python] = Result(NOT_NEEDED)  # until resolved below
                    work.append((need, target))
            queue = []
            results = pool.map(lambda nt: resolve(nt[0].requirement, nt[1]), work)
            for (need, target), result in zip(work, results):
                rows[need.name].results[target.python] = result
                for text in dependencies(result.requires, target):
                    queue.append((Need(text, (need.name,)), target))
    for row in rows.values():
        for target in targets:
            row.results.setdefault(target.python, Result(NOT_NEEDED))
    return list(rows.values())


def render_table(rows: list[Row], pythons: list[str], direct: set[str]) -> str:
    """A Markdown table: the direct dependencies, then any other package without a wheel
    everywhere; the rest of the closure in one line."""
    head = ["package", "needed by", *(f"Python {p}" for p in pythons)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    quiet = []
    for row in rows:
        all_wheels = all(row.results[p].status in (WHEEL, NOT_NEEDED) for p in pythons)
        if row.need.name not in direct and all_wheels:
            quiet.append(row.need.name)
            continue
        spec = str(Requirement(row.need.requirement).specifier) or "any"
        # A direct dependency names its pyproject groups; another, the packages requiring it.
        askers = row.need.needed_by if row.need.name in direct else row.needed_by
        cells = [f"{row.need.name} {spec}", ", ".join(askers)]
        cells += [row.results[p].cell() for p in pythons]
        lines.append("| " + " | ".join(cells) + " |")
    if quiet:
        lines.append("")
        lines.append(
            f"The {len(quiet)} packages these pull in have wheels for every version: "
            + ", ".join(sorted(quiet))
            + "."
        )
    return "\n".join(lines)


# --- make setup -------------------------------------------------------------------------------


def build_packages(python: str, have_headers: bool = False) -> list[str]:
    """Debian/Ubuntu packages that build a compiled sdist for this Python: C/C++ compilers,
    CMake and the interpreter's headers (pythonX.Y-dev, as the venv's Python is that one; not
    when they are there, as for a Python built from source, which Debian has no -dev for)."""
    return ["build-essential", "cmake", *([] if have_headers else [f"python{python}-dev"])]


def python_headers_present() -> bool:
    """Is this interpreter's Python.h installed (a venv's include path is its base's)?"""
    return Path(sysconfig.get_paths()["include"], "Python.h").is_file()


def choose_extras(
    needs_by_extra: dict[str, list[Need]],
    optional: set[str],
    direct: dict[str, Result],
    where: str,
) -> tuple[list[str], list[str]]:
    """(the extras to install, messages): an optional extra goes if one of its packages is
    missing here; a missing runtime or non-optional package is an error that says so."""
    extras = [e for e in needs_by_extra if e != "runtime"]
    messages = []
    for group, needs in needs_by_extra.items():
        missing = [n.name for n in needs if n.name in direct and direct[n.name].status == MISSING]
        if not missing:
            continue
        if group not in optional:
            raise SystemExit(
                f"armvision: {', '.join(missing)} ({group}) cannot be installed on {where}: "
                "no wheel and no source on the index (see the README, Supported platforms)"
            )
        extras.remove(group)
        messages.append(
            f"{', '.join(missing)}: no wheel and no source for {where}; installing without the "
            f"[{group}] extra (`armvision info` says what that leaves out)"
        )
    return extras, messages


def build_needs(
    installs: dict[str, Result], python: str, where: str, have_headers: bool = False
) -> tuple[list[str], list[str]]:
    """(Debian packages to install first, messages): the build packages if pip will compile
    a source distribution, else nothing."""
    compiled = sorted(name for name, r in installs.items() if r.status == SDIST_COMPILED)
    if not compiled:
        return [], []
    apt = build_packages(python, have_headers)
    return apt, [
        f"{', '.join(compiled)}: no wheel for {where}, only source that must be compiled; "
        f"installing a compiler, CMake and the Python headers first ({' '.join(apt)})"
    ]


def pip_resolve_command(requirements: list[str], index: str) -> list[str]:
    """What `pip install` of these would install here, dependencies included, as a report."""
    return [
        sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--quiet",
        "--report", "-", "--index-url", index, *requirements,
    ]  # fmt: skip


def parse_install_report(report_json: str) -> dict[str, tuple[str, bool]]:
    """{package: (version, from a wheel?)} of everything a ``--report`` would install."""
    installs = {}
    for item in json.loads(report_json)["install"]:
        name = canonicalize_name(item["metadata"]["name"])
        is_wheel = item["download_info"]["url"].split("#")[0].endswith(".whl")
        installs[name] = (item["metadata"]["version"], is_wheel)
    return installs


def project_compiles(index_page: dict) -> bool:
    """Does the project publish a wheel for a specific platform (so its source is compiled)?"""
    for entry in index_page.get("files", []):
        if entry["filename"].endswith(".whl"):
            try:
                tags = parse_wheel_filename(entry["filename"])[3]
            except (ValueError, InvalidVersion):
                continue
            if any(tag.platform != "any" for tag in tags):
                return True
    return False


def setup_here(extras: list[str], optional: set[str], index: str) -> int:
    target = Target(python=f"{sys.version_info[0]}.{sys.version_info[1]}", here=True)
    where = target.describe()
    headers = python_headers_present()
    pyproject = ROOT / "pyproject.toml"
    needs_by_extra = {"runtime": project_needs(pyproject, [])}
    for extra in extras:
        listed = {n.name for group in needs_by_extra.values() for n in group}
        needs_by_extra[extra] = [
            n
            for n in project_needs(pyproject, [extra])[len(needs_by_extra["runtime"]) :]
            if n.name not in listed
        ]

    def wanted(groups: list[str]) -> list[str]:
        return [
            n.requirement
            for g in groups
            for n in needs_by_extra[g]
            if applies(n.requirement, target)
        ]

    def say_and_install(messages: list[str], apt: list[str]) -> None:
        for message in messages:
            print(f"armvision: {message}", file=sys.stderr)
        if apt:  # silent when they are there already
            script = ROOT / "scripts" / "system-packages.sh"
            # apt's output goes to stderr: stdout carries only the extras, for the Makefile.
            subprocess.run(["sh", str(script), *apt], check=True, stdout=sys.stderr)

    # Everything at once, as `pip install` will: on x86_64 this succeeds and setup goes on as
    # before. Where it fails, each direct requirement is asked alone: optional extras with a
    # missing package go, and the build packages come first if one must be compiled (pip
    # builds an sdist's metadata, which may need them, before it can resolve).
    code, out, err = run_pip(pip_resolve_command(wanted(["runtime", *extras]), index))
    if code != 0:
        direct = [n for g in needs_by_extra.values() for n in g if applies(n.requirement, target)]
        with ThreadPoolExecutor(max_workers=4) as pool:
            resolved = pool.map(lambda n: resolve_one(n.requirement, target, index), direct)
            results = {n.name: r for n, r in zip(direct, resolved)}
        extras, messages = choose_extras(needs_by_extra, optional, results, where)
        kept = {n.name for g in ["runtime", *extras] for n in needs_by_extra[g]}
        apt, build_messages = build_needs(
            {k: v for k, v in results.items() if k in kept}, target.python, where, headers
        )
        say_and_install(messages + build_messages, apt)
        code, out, err = run_pip(pip_resolve_command(wanted(["runtime", *extras]), index))
        if code != 0:
            raise SystemExit(f"armvision: pip cannot resolve the dependencies here:\n{err}")
    installs = {
        name: Result(
            WHEEL
            if is_wheel
            else SDIST_COMPILED
            if project_compiles(fetch_index(name, index))
            else SDIST_PURE,
            version,
        )
        for name, (version, is_wheel) in parse_install_report(out).items()
    }
    apt, build_messages = build_needs(installs, target.python, where, headers)
    if apt and not _installed(apt):  # compiled sdists the direct requirements did not show
        say_and_install(build_messages, apt)
    print(",".join(extras))
    return 0


def _installed(packages: list[str]) -> bool:
    """Are these Debian packages installed already (then nothing more is said about them)?"""
    for package in packages:
        try:
            done = subprocess.run(
                ["dpkg-query", "-W", "-f=${db:Status-Status}", package],
                capture_output=True,
                text=True,
            )
        except FileNotFoundError:  # not Debian: system-packages.sh says what to install
            return False
        if done.returncode != 0 or done.stdout != "installed":
            return False
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--python", default="3.10,3.11,3.12,3.13", help="versions, comma separated")
    parser.add_argument("--machine", default="aarch64")
    parser.add_argument("--glibc", default="2.35", help="the target's glibc (Ubuntu 22.04: 2.35)")
    parser.add_argument("--index-url", default=PYPI)
    parser.add_argument("--jobs", type=int, default=4, help="pip processes at once")
    parser.add_argument("--here", action="store_true", help="make setup: plan for this machine")
    parser.add_argument("--extras", default="dev,realsense", help="--here: extras wanted")
    parser.add_argument("--optional", default="realsense", help="--here: extras that may go")
    args = parser.parse_args(argv)
    if args.here:
        extras = [e for e in args.extras.split(",") if e]
        return setup_here(extras, set(args.optional.split(",")), args.index_url)
    pythons = [p.strip() for p in args.python.split(",") if p.strip()]
    if not all(re.fullmatch(r"3\.\d+", p) for p in pythons):
        parser.error(f"--python: versions like 3.10,3.11, not {args.python!r}")
    major, minor = (int(x) for x in args.glibc.split("."))
    targets = [Target(p, args.machine, (major, minor)) for p in pythons]
    needs = project_needs(ROOT / "pyproject.toml")
    rows = resolve_closure(
        needs, targets, lambda req, t: resolve_one(req, t, args.index_url), args.jobs
    )
    versions = ", ".join(pythons)
    print(f"Linux {args.machine}, glibc {args.glibc}, CPython {versions}; index {args.index_url}\n")
    print(render_table(rows, pythons, {n.name for n in needs}))
    runtime_missing = [
        f"{row.need.name} (Python {p})"
        for row in rows
        if "runtime" in row.need.needed_by
        for p in pythons
        if row.results[p].status == MISSING
    ]
    if runtime_missing:
        print(f"\nruntime dependencies missing: {', '.join(runtime_missing)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
