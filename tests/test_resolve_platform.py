"""scripts/resolve_platform.py's decisions on hand-written pip reports and index pages.

Nothing here runs pip or reaches an index: the inputs are what they return, written out by hand
(the pupil-apriltags page is cut down from PyPI's), and the expected answers worked out from them.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parent.parent / "scripts" / "resolve_platform.py"
_spec = importlib.util.spec_from_file_location("resolve_platform", _PATH)
assert _spec is not None and _spec.loader is not None
rp = importlib.util.module_from_spec(_spec)
sys.modules["resolve_platform"] = rp  # dataclasses look their module up while being made
_spec.loader.exec_module(rp)

JAMMY_310 = rp.Target("3.10", "aarch64", (2, 35))
BOOKWORM_311 = rp.Target("3.11", "aarch64", (2, 36))


def _file(name: str, requires_python: str | None = None, yanked: bool = False) -> dict:
    return {"filename": name, "requires-python": requires_python, "yanked": yanked}


# Cut down from https://pypi.org/simple/pupil-apriltags/: wheels for x86_64 and macOS only.
APRILTAGS_PAGE = {
    "files": [
        _file("pupil-apriltags-1.0.4.tar.gz"),
        _file("pupil_apriltags-1.0.4.post10-cp311-cp311-manylinux_2_17_x86_64.whl", ">=3.6"),
        _file("pupil_apriltags-1.0.4.post10-cp311-cp311-macosx_11_0_arm64.whl", ">=3.6"),
        _file("pupil_apriltags-1.0.4.post10.tar.gz", ">=3.6"),
        _file("pupil_apriltags-1.0.4.post11.tar.gz", ">=3.6"),
        _file("pupil-apriltags-1.dev0.tar.gz"),  # a pre-release: not chosen
        _file("pupil_apriltags-9.0.tar.gz", yanked=True),
    ]
}


def test_every_manylinux_glibc_up_to_the_targets_is_passed_to_pip() -> None:
    args = JAMMY_310.pip_args()
    platforms = [args[i + 1] for i, a in enumerate(args) if a == "--platform"]
    # 2.17 (manylinux2014) to 2.35: 19 manylinux_2_Y tags, and the legacy alias.
    assert platforms[0] == "manylinux_2_17_aarch64"
    assert platforms[-2] == "manylinux_2_35_aarch64"
    assert platforms[-1] == "manylinux2014_aarch64"
    assert len(platforms) == 35 - 17 + 1 + 1
    assert args[-6:] == ["--python-version", "3.10", "--implementation", "cp", "--abi", "cp310"]
    assert rp.Target("3.11", here=True).pip_args() == []


def test_markers_are_evaluated_for_the_target_python_not_the_running_one() -> None:
    tomli = "tomli>=2.0; python_version < '3.11'"
    assert rp.applies(tomli, JAMMY_310)
    assert not rp.applies(tomli, BOOKWORM_311)
    assert rp.without_marker(tomli) == "tomli>=2.0"
    requires = ["numpy>=2; python_version >= '3.9'", "pytest; extra == 'test'", "colorama"]
    assert rp.dependencies(requires, JAMMY_310) == [requires[0], "colorama"]


def test_the_wheel_is_read_from_pips_report() -> None:
    report = {
        "version": "1",
        "install": [
            {
                "download_info": {
                    "url": "https://files.example/opencv_python_headless-4.14.0.94-cp37-abi3-"
                    "manylinux2014_aarch64.manylinux_2_17_aarch64.whl"
                },
                "metadata": {
                    "name": "opencv-python-headless",
                    "version": "4.14.0.94",
                    "requires_dist": ['numpy>=2; python_version >= "3.9"'],
                },
            }
        ],
    }
    result = rp.parse_report(json.dumps(report))
    assert result.status == rp.WHEEL
    assert result.version == "4.14.0.94"
    assert result.filename.startswith("opencv_python_headless-4.14.0.94-cp37-abi3-")
    assert result.requires == ('numpy>=2; python_version >= "3.9"',)
    assert result.cell() == "wheel 4.14.0.94"


def test_a_project_with_platform_wheels_elsewhere_is_a_compiled_sdist() -> None:
    result = rp.classify_without_wheel("pupil-apriltags>=1.0.4", "3.10", APRILTAGS_PAGE)
    # post11 is the newest non-yanked final release; 1.dev0 is a pre-release, 9.0 is yanked.
    assert (result.status, result.version) == (rp.SDIST_COMPILED, "1.0.4.post11")
    assert result.cell() == "**sdist-only (compiled)** 1.0.4.post11"
    capped = rp.classify_without_wheel("pupil-apriltags<1.0.4.post11", "3.10", APRILTAGS_PAGE)
    assert capped.version == "1.0.4.post10"


def test_an_sdist_with_no_platform_wheels_anywhere_is_pure_python() -> None:
    page = {"files": [_file("filterpy-1.4.5.zip"), _file("modern_robotics-1.1.1-py3-none-any.whl")]}
    result = rp.classify_without_wheel("filterpy>=1.4", "3.12", page)
    assert (result.status, result.version) == (rp.SDIST_PURE, "1.4.5")


def test_requires_python_and_an_empty_page_leave_nothing() -> None:
    page = {"files": [_file("newpkg-2.0.tar.gz", ">=3.12")]}
    assert rp.classify_without_wheel("newpkg", "3.10", page).status == rp.MISSING
    assert rp.classify_without_wheel("newpkg", "3.12", page).version == "2.0"
    # pyrealsense2 publishes no sdist at all: where no wheel fits, it is missing.
    page = {"files": [_file("pyrealsense2-2.56.5.9235-cp310-cp310-manylinux_2_31_aarch64.whl")]}
    assert rp.classify_without_wheel("pyrealsense2>=2.54", "3.11", page).status == rp.MISSING
    assert rp.Result(rp.MISSING).cell() == "**missing**"


def test_project_needs_lists_each_package_once_with_everyone_who_asks(tmp_path: Path) -> None:
    pyproject = tmp_path / "pyproject.toml"
    pyproject.write_text(
        "[project]\nname = 'x'\ndependencies = ['numpy>=1.24', \"tomli; python_version<'3.11'\"]\n"
        "[project.optional-dependencies]\n"
        "onnx = ['onnxruntime>=1.16']\ndev = ['pytest>=8', 'onnxruntime>=1.16']\n"
    )
    needs = rp.project_needs(pyproject)
    assert [(n.name, n.needed_by) for n in needs] == [
        ("numpy", ("runtime",)),
        ("tomli", ("runtime",)),
        ("onnxruntime", ("onnx", "dev")),
        ("pytest", ("dev",)),
    ]
    assert [n.name for n in rp.project_needs(pyproject, ["dev"])] == [
        "numpy",
        "tomli",
        "pytest",
        "onnxruntime",
    ]


def test_the_closure_follows_wheel_requirements_and_the_table_shows_what_is_not_a_wheel() -> None:
    # A hand-made world: app needs lib (wheel) which needs helper (sdist only on 3.12) and
    # tiny (wheel), and on 3.12 (a newer lib there) core too; tomli only below 3.11; tiny is
    # also required by app itself, tomli by lib.
    world = {
        ("app", "3.10"): rp.Result(rp.WHEEL, "1.0", requires=("lib>=2", "tiny")),
        ("app", "3.12"): rp.Result(rp.WHEEL, "1.0", requires=("lib>=2", "tiny")),
        ("lib", "3.10"): rp.Result(rp.WHEEL, "2.1", requires=("helper", "tiny", "tomli")),
        ("lib", "3.12"): rp.Result(rp.WHEEL, "3.0", requires=("helper", "tiny", "core==3.0")),
        ("core", "3.10"): rp.Result(rp.MISSING),  # would be, but lib 2.1 does not need it
        ("helper", "3.10"): rp.Result(rp.WHEEL, "0.3"),
        ("helper", "3.12"): rp.Result(rp.SDIST_COMPILED, "0.3"),
        ("tiny", "3.10"): rp.Result(rp.WHEEL, "5"),
        ("tiny", "3.12"): rp.Result(rp.WHEEL, "5"),
    }
    asked = []

    def resolve(requirement: str, target) -> object:
        asked.append((requirement, target.python))
        if not rp.applies(requirement, target):
            return rp.Result(rp.NOT_NEEDED)
        name = rp.Requirement(requirement).name
        return world.get((name, target.python), rp.Result(rp.WHEEL, "9"))

    needs = [rp.Need("app>=1", ("runtime",)), rp.Need("tomli; python_version<'3.11'", ("runtime",))]
    targets = [rp.Target("3.10"), rp.Target("3.12")]
    rows = rp.resolve_closure(needs, targets, resolve, jobs=2)
    assert [r.need.name for r in rows] == ["app", "tomli", "lib", "tiny", "helper", "core"]
    assert len(asked) == 5 * 2 + 1  # each package once per version it is needed on
    assert ("core==3.0", "3.10") not in asked
    assert list(rows[3].needed_by) == ["app", "lib"]
    assert list(rows[1].needed_by) == ["runtime", "lib"]  # the table shows "runtime" only
    table = rp.render_table(rows, ["3.10", "3.12"], {"app", "tomli"})
    assert table.splitlines() == [
        "| package | needed by | Python 3.10 | Python 3.12 |",
        "|---|---|---|---|",
        "| app >=1 | runtime | wheel 1.0 | wheel 1.0 |",
        "| tomli any | runtime | wheel 9 | - |",
        "| helper any | lib | wheel 0.3 | **sdist-only (compiled)** 0.3 |",
        "",
        "The 3 packages these pull in have wheels for every version: core, lib, tiny.",
    ]


def test_setup_drops_an_optional_extra_whose_package_is_missing() -> None:
    needs = {
        "runtime": [rp.Need("numpy", ("runtime",)), rp.Need("pupil-apriltags", ("runtime",))],
        "dev": [rp.Need("pytest", ("dev",))],
        "realsense": [rp.Need("pyrealsense2>=2.54", ("realsense",))],
    }
    direct = {
        "numpy": rp.Result(rp.WHEEL, "2.2.6"),
        "pupil-apriltags": rp.Result(rp.SDIST_COMPILED, "1.0.4.post11"),
        "pytest": rp.Result(rp.WHEEL, "9"),
        "pyrealsense2": rp.Result(rp.MISSING),
    }
    where = "Linux aarch64, Python 3.11"
    extras, messages = rp.choose_extras(needs, {"realsense"}, direct, where)
    assert extras == ["dev"]
    assert messages == [
        "pyrealsense2: no wheel and no source for Linux aarch64, Python 3.11; installing "
        "without the [realsense] extra (`armvision info` says what that leaves out)"
    ]
    # Nothing missing (x86_64): every extra stays, nothing said.
    ok = dict(direct, pyrealsense2=rp.Result(rp.WHEEL, "2.59"))
    assert rp.choose_extras(needs, {"realsense"}, ok, where) == (["dev", "realsense"], [])
    # A missing runtime package is an error, not a silent drop.
    with pytest.raises(SystemExit, match=r"numpy \(runtime\) cannot be installed"):
        rp.choose_extras(needs, {"realsense"}, dict(direct, numpy=rp.Result(rp.MISSING)), where)


def test_setup_installs_build_packages_only_for_a_compiled_sdist() -> None:
    where = "Linux aarch64, Python 3.11"
    installs = {
        "numpy": rp.Result(rp.WHEEL, "2.2.6"),
        "filterpy": rp.Result(rp.SDIST_PURE, "1.4.5"),
    }
    assert rp.build_needs(installs, "3.11", where) == ([], [])
    installs["pupil-apriltags"] = rp.Result(rp.SDIST_COMPILED, "1.0.4.post11")
    apt, messages = rp.build_needs(installs, "3.11", where)
    assert apt == ["build-essential", "cmake", "python3.11-dev"]
    assert messages == [
        "pupil-apriltags: no wheel for Linux aarch64, Python 3.11, only source that must be "
        "compiled; installing a compiler, CMake and the Python headers first "
        "(build-essential cmake python3.11-dev)"
    ]
    # A Python built from source (pyenv on Ubuntu 20.04) has its headers and no Debian -dev.
    apt, _ = rp.build_needs(installs, "3.10", where, have_headers=True)
    assert apt == ["build-essential", "cmake"]


def test_the_install_report_says_which_come_from_a_wheel() -> None:
    report = {
        "install": [
            {
                "download_info": {"url": "https://f/numpy-2.2.6-cp311-cp311-x.whl#sha256=00"},
                "metadata": {"name": "NumPy", "version": "2.2.6"},
            },
            {
                "download_info": {"url": "https://f/pupil_apriltags-1.0.4.post11.tar.gz"},
                "metadata": {"name": "pupil_apriltags", "version": "1.0.4.post11"},
            },
        ]
    }
    assert rp.parse_install_report(json.dumps(report)) == {
        "numpy": ("2.2.6", True),
        "pupil-apriltags": ("1.0.4.post11", False),
    }


def _report(*items: tuple[str, str, str]) -> str:
    """A pip --report of (name, version, file name) items."""
    return json.dumps(
        {
            "install": [
                {"download_info": {"url": f"https://f/{f}"}, "metadata": {"name": n, "version": v}}
                for n, v, f in items
            ]
        }
    )


def test_setup_here_on_aarch64_311_drops_realsense_and_installs_build_packages_first(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The whole flow with pip, the index and apt replaced by what they answered on arm64
    Debian 12 (Python 3.11): the full resolution fails (pyrealsense2), each package alone says
    why, the build packages are installed before pip is asked again, and the extras printed
    leave realsense out."""
    events: list[tuple[str, ...]] = []
    second = _report(
        ("numpy", "2.4.6", "numpy-2.4.6-cp311-cp311-manylinux_2_28_aarch64.whl"),
        ("pupil_apriltags", "1.0.4.post11", "pupil_apriltags-1.0.4.post11.tar.gz"),
    )
    answers = iter([(1, "", "ERROR: No matching distribution found for pyrealsense2>=2.54"),
                    (0, second, "")])  # fmt: skip

    def run_pip(command):
        events.append(("pip", "pyrealsense2>=2.54" in command))
        return next(answers)

    def resolve_one(requirement, target, index):
        name = rp.Requirement(requirement).name
        if name == "pyrealsense2":
            return rp.Result(rp.MISSING)
        if name == "pupil-apriltags":
            return rp.Result(rp.SDIST_COMPILED, "1.0.4.post11")
        return rp.Result(rp.WHEEL, "1")

    def run(command, **kwargs):
        if command[0] == "dpkg-query":  # the build packages are there by now
            return rp.subprocess.CompletedProcess(command, 0, "installed", "")
        events.append(("apt", *command[2:]))
        return rp.subprocess.CompletedProcess(command, 0)

    monkeypatch.setattr(rp, "run_pip", run_pip)
    monkeypatch.setattr(rp, "resolve_one", resolve_one)
    monkeypatch.setattr(rp, "fetch_index", lambda name, index: APRILTAGS_PAGE)
    monkeypatch.setattr(rp, "python_headers_present", lambda: False)
    monkeypatch.setattr(rp.subprocess, "run", run)
    monkeypatch.setattr(rp.sys, "version_info", (3, 11, 2))
    assert rp.setup_here(["dev", "realsense"], {"realsense"}, rp.PYPI) == 0
    out, err = capsys.readouterr()
    assert out == "dev\n"
    assert events == [
        ("pip", True),
        ("apt", "build-essential", "cmake", "python3.11-dev"),
        ("pip", False),  # asked again without pyrealsense2, after the build packages
    ]
    assert "pyrealsense2: no wheel and no source" in err
    assert "pupil-apriltags: no wheel for Linux" in err and "(build-essential cmake" in err
    assert err.count("pupil-apriltags") == 1  # said once, not again after the second resolution


def test_setup_here_where_everything_resolves_asks_pip_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    calls = []
    wheels = _report(("numpy", "2.4.6", "numpy-2.4.6-cp311-cp311-manylinux_2_28_x86_64.whl"))
    monkeypatch.setattr(rp, "run_pip", lambda command: calls.append(command) or (0, wheels, ""))
    assert rp.setup_here(["dev", "realsense"], {"realsense"}, rp.PYPI) == 0
    assert capsys.readouterr() == ("dev,realsense\n", "")
    assert len(calls) == 1
    assert "pyrealsense2>=2.54" in calls[0] and "pytest>=8" in calls[0]
