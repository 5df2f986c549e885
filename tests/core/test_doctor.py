"""`clutt3r doctor`: the report, its exit status, and the hint for a backend that is missing a package."""

from __future__ import annotations

import json

import pytest
from rich.console import Console

import clutt3r_core.doctor as doctor
from clutt3r_core.commands.doctor import doctor_command, render
from clutt3r_core.registry import KINDS, REGISTRY
from clutt3r_core.system_libs import LibraryUse, LinkScan, check_system_libraries


def _text(report) -> str:
    con = Console(record=True, width=250, color_system=None)
    render(report, con)
    return con.export_text()


def test_report_lists_versions_and_every_backend_kind() -> None:
    report = doctor.diagnose(check_libraries=False)
    assert [p.label for p in report.packages] == [label for label, _ in doctor.KEY_PACKAGES]
    assert all(p.installed for p in report.packages), report.missing_packages  # all core dependencies
    assert report.kinds == KINDS
    hsv = [b for b in report.backends if b.kind == "mask_embedder" and b.name == "appearance-hsv"]
    assert hsv and hsv[0].available and hsv[0].is_default and hsv[0].hint == ""
    assert report.system.skipped and report.ok
    text = _text(report)
    for kind in KINDS:
        assert kind in text
    assert "numpy" in text and "rerun-sdk" in text


def test_fake_backend_with_a_missing_package_shows_its_hint() -> None:
    REGISTRY.register("grasp_planner", "fake-planner", "clutt3r_no_such_module:Planner",
                      requires=("clutt3r_no_such_module=clutt3r-no-such-dist",), extra="fakegrasp",
                      description="a test double")
    try:
        report = doctor.diagnose(check_libraries=False)
    finally:
        REGISTRY.unregister("grasp_planner", "fake-planner")
    (line,) = [b for b in report.backends if b.name == "fake-planner"]
    assert line.kind == "grasp_planner" and not line.available and not line.is_default
    assert line.missing == ("clutt3r-no-such-dist",)
    assert line.hint == "pip install 'clutt3r[fakegrasp]'"
    assert "pip install 'clutt3r[fakegrasp]'" in _text(report)
    (j,) = [b for b in report.to_json()["backends"] if b["name"] == "fake-planner"]
    assert j["available"] is False and j["hint"] == "pip install 'clutt3r[fakegrasp]'"
    assert report.ok, "an optional backend that cannot be built does not make the core fail"


def _libusb_missing() -> doctor.SystemLibraries:
    scan = LinkScan(("/sp",), 1, (LibraryUse("libusb-1.0.so.0", None, "open3d/libOpen3D.so.0.19", "open3d-cpu 0.19.0"),),
                    (), frozenset(), True, 0.1)
    return doctor.SystemLibraries(check_system_libraries(scan, frozenset({"libusb-1.0-0"}), frozenset()), "", ())


@pytest.mark.parametrize("as_json", [False, True])
def test_missing_system_library_exits_1_naming_it_and_the_fix(monkeypatch, capsys, as_json: bool) -> None:
    monkeypatch.setattr(doctor, "system_libraries", _libusb_missing)
    with pytest.raises(SystemExit) as exc:
        doctor_command(json=as_json)
    assert exc.value.code == 1
    out = capsys.readouterr().out
    if as_json:
        d = json.loads(out)
        assert d["ok"] is False and d["system"]["ok"] is False
        assert d["system"]["fix_command"].endswith("apt-get install -y libusb-1.0-0")
        assert d["system"]["check"]["problems"][0]["soname"] == "libusb-1.0.so.0"
    else:
        flat = " ".join(out.split())  # rich wraps long lines
        assert "libusb-1.0.so.0 is not found" in flat and "open3d/libOpen3D.so.0.19" in flat
        assert "apt-get install -y libusb-1.0-0" in flat and "not ok" in flat


def test_not_installed_listed_package_is_a_failure_too() -> None:
    s = doctor.SystemLibraries(None, "ldd is not available", ("libusb-1.0-0",))
    assert not s.ok and s.fix_command.endswith("apt-get install -y libusb-1.0-0")


def test_doctor_on_this_machine_exits_0(capsys) -> None:
    """The real check (ldd + dpkg over .venv): the scripts installed what the wheels need."""
    with pytest.raises(SystemExit) as exc:
        doctor_command(json=True)
    d = json.loads(capsys.readouterr().out)
    assert exc.value.code == 0, d["system"]
    assert d["ok"] is True and d["system"]["fix_command"] == ""
    check = d["system"]["check"]
    if check is not None:  # None only without ldd
        assert check["scan"]["n_files"] > 50 and check["problems"] == []


def test_doctor_is_a_cli_command() -> None:
    from clutt3r_core.cli import available_commands

    assert available_commands()["doctor"] is doctor_command
