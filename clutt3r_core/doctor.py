"""What this installation has and lacks, for ``clutt3r doctor``.

``diagnose()`` gathers, without importing any heavy package: the Python and key package
versions (from the installed metadata), the system libraries that the wheels need and this
machine lacks (``clutt3r_core.system_libs``: ``ldd`` + ``dpkg-query -S``, the same check as
``tests/test_system_libs.py``), Debian's chromium and playwright for the browser tests, and for
every backend kind of the registry which backends can be built here and which extra or package
would add the others. ``DoctorReport.ok`` is what the command's exit status reports: the core
works (no required system library or core package is missing).
"""

from __future__ import annotations

import dataclasses
import os
import platform
import shutil
import subprocess
import sys
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from clutt3r_core.system_libs import (
    SystemLibCheck,
    check_system_libraries,
    read_package_list,
    repo_scripts_dir,
    scan_site_packages,
)

__all__ = [
    "KEY_PACKAGES",
    "PackageVersion",
    "BrowserStatus",
    "BackendLine",
    "SystemLibraries",
    "DoctorReport",
    "diagnose",
    "system_libraries",
]

KEY_PACKAGES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("numpy", ("numpy",)),
    ("torch", ("torch",)),
    ("open3d", ("open3d-cpu", "open3d")),
    ("viser", ("viser",)),
    ("onnxruntime", ("onnxruntime", "onnxruntime-gpu")),
    ("opencv", ("opencv-python-headless", "opencv-python", "opencv-contrib-python-headless",
                "opencv-contrib-python")),
    ("trimesh", ("trimesh",)),
    ("scikit-image", ("scikit-image",)),
    ("rerun-sdk", ("rerun-sdk",)),
)
"""``(label, distributions that provide it)``: each is a core dependency in pyproject.toml."""

CHROMIUM = "/usr/bin/chromium"


@dataclass(frozen=True)
class PackageVersion:
    """``label`` (e.g. "opencv") provided by ``distribution`` at ``version``; both None when missing."""

    label: str
    distribution: str | None
    version: str | None

    @property
    def installed(self) -> bool:
        return self.version is not None


@dataclass(frozen=True)
class BrowserStatus:
    """What the browser tests need: Debian's chromium (driven by playwright).

    Attributes:
        chromium: path of the executable, None when absent.
        chromium_version: what ``chromium --version`` printed, None when absent or it failed.
        playwright: installed playwright version, None when not importable.
    """

    chromium: str | None
    chromium_version: str | None
    playwright: str | None

    @property
    def ready(self) -> bool:
        return self.chromium is not None and self.playwright is not None


@dataclass(frozen=True)
class BackendLine:
    """One registered backend: whether it can be built here and, if not, how to make it so."""

    kind: str
    name: str
    available: bool
    is_default: bool
    missing: tuple[str, ...]
    hint: str
    description: str
    source: str


@dataclass(frozen=True)
class SystemLibraries:
    """The system-library part of the report.

    Attributes:
        check: the check, None when it could not run (see ``skipped``).
        skipped: why the check did not run ('' when it did).
        not_installed: packages of ``scripts/system-packages.txt`` that dpkg lacks (empty outside
            a checkout or off Debian).
    """

    check: SystemLibCheck | None
    skipped: str
    not_installed: tuple[str, ...]

    @property
    def fix_packages(self) -> tuple[str, ...]:
        """Debian packages to install so that no required library is missing."""
        pkgs = list(self.not_installed)
        if self.check is not None:
            pkgs += [p.package for p in self.check.missing if p.package]
        return tuple(dict.fromkeys(pkgs))

    @property
    def fix_command(self) -> str:
        """The apt-get command that installs ``fix_packages`` ('' when nothing is missing)."""
        if not self.fix_packages:
            return ""
        sudo = "sudo " if hasattr(os, "geteuid") and os.geteuid() != 0 else ""
        return f"{sudo}apt-get install -y {' '.join(self.fix_packages)}"

    @property
    def ok(self) -> bool:
        return not self.not_installed and (self.check is None or not self.check.missing)


@dataclass(frozen=True)
class DoctorReport:
    """Everything ``clutt3r doctor`` shows. ``ok``: the core works here."""

    python: str
    executable: str
    platform: str
    packages: tuple[PackageVersion, ...]
    system: SystemLibraries
    browser: BrowserStatus
    backends: tuple[BackendLine, ...]
    plugin_errors: tuple[str, ...]
    kinds: tuple[str, ...] = ()
    """Every backend kind of the registry (kinds without a registered backend included)."""

    @property
    def missing_packages(self) -> tuple[str, ...]:
        return tuple(p.label for p in self.packages if not p.installed)

    @property
    def ok(self) -> bool:
        return self.system.ok and not self.missing_packages

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (``--json``): the fields, plus ``ok`` and the fix command."""
        d = dataclasses.asdict(self)
        sys_d = d["system"]
        if sys_d["check"] is not None:
            scan = sys_d["check"].pop("scan")
            sys_d["check"]["scan"] = {
                "site_packages": scan["site_packages"], "n_files": scan["n_files"],
                "seconds": round(scan["seconds"], 3), "dpkg": scan["dpkg"],
            }
        sys_d["fix_command"] = self.system.fix_command
        sys_d["ok"] = self.system.ok
        d["browser"]["ready"] = self.browser.ready
        d["missing_packages"] = list(self.missing_packages)
        d["ok"] = self.ok
        return d


def _package_versions() -> tuple[PackageVersion, ...]:
    out = []
    for label, dists in KEY_PACKAGES:
        found = PackageVersion(label, None, None)
        for dist in dists:
            try:
                found = PackageVersion(label, dist, version(dist))
                break
            except PackageNotFoundError:
                continue
        out.append(found)
    return tuple(out)


def _browser() -> BrowserStatus:
    path = CHROMIUM if os.access(CHROMIUM, os.X_OK) else shutil.which("chromium")
    ver = None
    if path:
        try:
            proc = subprocess.run([path, "--version"], capture_output=True, text=True, timeout=30, check=False)
            ver = proc.stdout.strip() or None
        except (OSError, subprocess.TimeoutExpired):
            ver = None
    try:
        pw: str | None = version("playwright")
    except PackageNotFoundError:
        pw = None
    return BrowserStatus(path, ver, pw)


def _backends() -> tuple[tuple[BackendLine, ...], tuple[str, ...]]:
    from clutt3r_core.registry import KINDS, REGISTRY, backend_status, default_backend

    lines = []
    for kind in KINDS:
        default = default_backend(kind)
        for st in backend_status(kind):
            lines.append(BackendLine(
                kind=kind, name=st.spec.name, available=st.available, is_default=st.spec.name == default,
                missing=st.missing, hint=st.hint, description=st.spec.description, source=st.spec.source,
            ))
    return tuple(lines), tuple(REGISTRY.plugin_errors)


def _dpkg_not_installed(packages: frozenset[str]) -> tuple[str, ...]:
    if not packages or shutil.which("dpkg-query") is None:
        return ()
    out = []
    for p in sorted(packages):
        proc = subprocess.run(["dpkg-query", "-W", "-f=${Status}", p], capture_output=True, text=True, check=False)
        if proc.stdout.strip() != "install ok installed":
            out.append(p)
    return tuple(out)


def system_libraries() -> SystemLibraries:
    """Run the system-library check on this interpreter's site-packages.

    Inside a source checkout the install list and the base image's list (``scripts/``) are
    compared too; elsewhere only libraries that ``ldd`` cannot find are reported.
    """
    scripts = repo_scripts_dir()
    install = read_package_list(scripts / "system-packages.txt") if scripts else None
    base_file = scripts / "base-image-packages.txt" if scripts else None
    base = read_package_list(base_file) if base_file is not None and base_file.is_file() else None
    try:
        scan = scan_site_packages()
    except FileNotFoundError as e:
        return SystemLibraries(None, str(e), _dpkg_not_installed(install or frozenset()))
    check = check_system_libraries(scan, install, base)
    return SystemLibraries(check, "", _dpkg_not_installed(install or frozenset()))


def diagnose(*, check_libraries: bool = True) -> DoctorReport:
    """Gather the report. ``check_libraries=False`` skips the ~3 s ldd scan (reported as skipped)."""
    system = system_libraries() if check_libraries else SystemLibraries(None, "skipped on request", ())
    from clutt3r_core.registry import KINDS

    backends, plugin_errors = _backends()
    return DoctorReport(
        python=platform.python_version(),
        executable=sys.executable,
        platform=platform.platform(),
        packages=_package_versions(),
        system=system,
        browser=_browser(),
        backends=backends,
        plugin_errors=plugin_errors,
        kinds=KINDS,
    )
