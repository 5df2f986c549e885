"""Which system libraries the installed wheels link against, and which Debian package gives each.

A wheel's compiled extension modules and the libraries it bundles (``*.libs/``, ``open3d/``)
may still link against libraries of the system: open3d-cpu's ``libOpen3D.so`` links
``libusb-1.0.so.0``, which the project's base image lacks, so ``import open3d`` failed on a
fresh machine. ``scan_site_packages`` runs ``ldd`` on every ELF shared object under
site-packages and maps each library resolved outside it to its Debian package
(``dpkg-query -S``); ``check_system_libraries`` compares those packages with the project's
install list (``scripts/system-packages.txt``) and the base image's list
(``scripts/base-image-packages.txt``). ``tests/test_system_libs.py`` and ``clutt3r doctor``
both use them. Nothing is cached: one scan of a full venv takes about 3 s.
"""

from __future__ import annotations

import fnmatch
import os
import shutil
import subprocess
import sys
import sysconfig
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from importlib.metadata import distributions
from pathlib import Path
from typing import Literal

__all__ = [
    "LibraryUse",
    "LinkScan",
    "SystemLibProblem",
    "SystemLibCheck",
    "NEVER_LOADED",
    "site_packages_dirs",
    "scan_site_packages",
    "check_system_libraries",
    "parse_ldd",
    "probable_package",
    "read_package_list",
    "repo_scripts_dir",
]

NEVER_LOADED: tuple[tuple[str, str, str], ...] = (
    (
        "open3d/open3d_tf_ops.so",
        "libtensorflow_framework.so.2",
        "open3d's TensorFlow ops: loaded only by `import open3d.ml.tf`, which first imports tensorflow "
        "(not a dependency of ours; without it that import fails with 'No module named tensorflow')",
    ),
)
"""``(file glob relative to site-packages, soname, why)``: libraries that ``ldd`` cannot find but that
are never loaded in practice. Investigated on the python base image, open3d-cpu 0.19/0.20."""

BUNDLED_REASON = (
    "a file of that name lies in site-packages: ldd checks each file alone, without the RPATH of "
    "the module that loads it (scipy.libs/libgfortran's libquadmath) or the library an earlier "
    "import loaded (open3d.ml.torch imports torch first, which loads torch/lib/libtorch_cpu.so)"
)

_LDD_BATCH = 64  # files per ldd call: few processes, short argument lists


def site_packages_dirs() -> tuple[Path, ...]:
    """The running interpreter's site-packages folders (purelib and platlib, usually one)."""
    out: list[Path] = []
    for key in ("purelib", "platlib"):
        p = Path(sysconfig.get_paths()[key]).resolve()
        if p.is_dir() and p not in out:
            out.append(p)
    return tuple(out)


def repo_scripts_dir() -> Path | None:
    """``scripts/`` of the source checkout this package runs from (editable install), if any."""
    d = Path(__file__).resolve().parents[1] / "scripts"
    return d if (d / "system-packages.txt").is_file() else None


def read_package_list(path: str | Path) -> frozenset[str]:
    """Debian package names of a list file: one a line, '#' starts a comment, ':arch' dropped."""
    names = set()
    for line in Path(path).read_text().splitlines():
        word = line.split("#", 1)[0].strip()
        if word:
            names.add(word.split()[0].split(":")[0])
    return frozenset(names)


def probable_package(soname: str) -> str | None:
    """The Debian package that Debian's naming rule gives a library (policy 8.1), or None.

    ``libusb-1.0.so.0`` -> ``libusb-1.0-0``; ``libGL.so.1`` -> ``libgl1``. Only a guess: used to
    name a package for a library that is not installed, so ``dpkg -S`` cannot tell.
    """
    name, sep, version = soname.partition(".so.")
    if not sep or not name or not version:
        return None
    version = version.split(".")[0]
    joiner = "-" if name[-1].isdigit() else ""
    return f"{name}{joiner}{version}".lower().replace("_", "-")


@dataclass(frozen=True)
class LibraryUse:
    """One library, outside site-packages or not found, that one file of site-packages needs.

    Attributes:
        soname: the name the file asks for (``DT_NEEDED``), e.g. ``libusb-1.0.so.0``.
        resolved: absolute path ``ldd`` resolved it to; None when ``ldd`` says "not found".
        needed_by: the file that needs it, relative to its site-packages folder.
        distribution: ``"name version"`` of the installed distribution whose RECORD lists that
            file ("unknown" when none does).
    """

    soname: str
    resolved: str | None
    needed_by: str
    distribution: str


@dataclass(frozen=True)
class LinkScan:
    """What ``ldd`` and ``dpkg-query -S`` said about the shared objects of site-packages.

    Attributes:
        site_packages: the folders scanned.
        n_files: ELF shared objects examined.
        uses: every dependency resolved outside site-packages, and every "not found".
        owners: ``(resolved path, Debian package)`` for each resolved path dpkg knows.
        bundled: basenames of all shared objects inside site-packages.
        dpkg: whether ``dpkg-query`` was there (False: no package mapping).
        seconds: wall time of the scan.
    """

    site_packages: tuple[str, ...]
    n_files: int
    uses: tuple[LibraryUse, ...]
    owners: tuple[tuple[str, str], ...]
    bundled: frozenset[str]
    dpkg: bool
    seconds: float

    def owner(self, path: str) -> str | None:
        return dict(self.owners).get(path)


@dataclass(frozen=True)
class SystemLibProblem:
    """A system library the wheels need that this machine or the install list may not provide.

    Attributes:
        kind: "not-found" (``ldd`` cannot find it: the import fails), "unlisted" (installed, from a
            Debian package in neither list: a fresh machine lacks it) or "unowned" (resolved to a
            system path no Debian package owns).
        soname: the library.
        package: its Debian package (``dpkg -S``), or for "not-found" the probable one (Debian's
            naming rule; see ``package_is_guess``); None when unknown.
        package_is_guess: True when ``package`` comes from the naming rule.
        needed_by: the files of site-packages that need it (relative paths).
        distributions: the installed distributions of those files.
    """

    kind: Literal["not-found", "unlisted", "unowned"]
    soname: str
    package: str | None
    package_is_guess: bool
    needed_by: tuple[str, ...]
    distributions: tuple[str, ...]

    def __str__(self) -> str:
        files = ", ".join(self.needed_by[:3]) + (f" (+{len(self.needed_by) - 3})" if len(self.needed_by) > 3 else "")
        dists = ", ".join(self.distributions)
        pkg = f"Debian package {'probably ' if self.package_is_guess else ''}{self.package}" if self.package else "no known Debian package"
        if self.kind == "not-found":
            return f"{self.soname} is not found ({pkg}); needed by {files} [{dists}]"
        if self.kind == "unowned":
            return f"{self.soname} resolves outside Debian's packages; needed by {files} [{dists}]"
        return (f"{self.soname} comes from {pkg}, which is in neither scripts/system-packages.txt nor "
                f"scripts/base-image-packages.txt; needed by {files} [{dists}]")


@dataclass(frozen=True)
class SystemLibCheck:
    """The verdict of ``check_system_libraries``.

    Attributes:
        scan: the scan checked.
        problems: one per (kind, library), sorted.
        allowed: ``(soname, why)`` for each library ldd cannot find that is fine anyway.
        packages: the Debian packages the wheels' system libraries come from, sorted.
        lists_checked: whether the install list and the base list were compared (False: no lists).
    """

    scan: LinkScan
    problems: tuple[SystemLibProblem, ...]
    allowed: tuple[tuple[str, str], ...]
    packages: tuple[str, ...]
    lists_checked: bool

    @property
    def missing(self) -> tuple[SystemLibProblem, ...]:
        """The libraries that are not there now (imports fail)."""
        return tuple(p for p in self.problems if p.kind == "not-found")


def parse_ldd(output: str, files: Sequence[str]) -> dict[str, list[tuple[str, str | None]]]:
    """``{file: [(soname, resolved path or None), ...]}`` from the output of ``ldd FILE...``.

    ``ldd`` heads each file's block with ``FILE:`` only when given several files. Lines without
    ``=>`` (the program interpreter, ``linux-vdso``, "statically linked") are skipped.
    """
    out: dict[str, list[tuple[str, str | None]]] = {f: [] for f in files}
    current = files[0] if len(files) == 1 else None
    for line in output.splitlines():
        if not line[:1].isspace() and line.endswith(":") and line[:-1] in out:
            current = line[:-1]
            continue
        if current is None or "=>" not in line:
            continue
        name, _, rest = (s.strip() for s in line.partition("=>"))
        if rest.startswith("not found"):
            out[current].append((name, None))
            continue
        path = rest.split(" (", 1)[0].strip()
        if path.startswith("/"):
            out[current].append((name, path))
    return out


def _shared_objects(roots: Iterable[Path]) -> list[Path]:
    found = []
    for root in roots:
        for dirpath, _dirs, names in os.walk(root):
            for n in names:
                if not (n.endswith(".so") or ".so." in n):
                    continue
                p = Path(dirpath, n)
                if p.is_symlink() or not p.is_file():
                    continue  # a symlink's target is scanned as a file itself
                try:
                    with open(p, "rb") as fh:
                        if fh.read(4) != b"\x7fELF":
                            continue
                except OSError:
                    continue
                found.append(p)
    return sorted(found)


def _distribution_of_files(roots: Sequence[Path]) -> dict[Path, str]:
    """Shared-object paths -> ``"name version"`` from the RECORD of each installed distribution."""
    out: dict[Path, str] = {}
    for dist in distributions(path=[str(r) for r in roots]):
        label = f"{dist.metadata['Name']} {dist.version}"
        for f in dist.files or ():
            s = str(f)
            if s.endswith(".so") or ".so." in s:
                out[Path(os.path.normpath(dist.locate_file(f)))] = label
    return out


def _usrmerge_variants(path: str) -> list[str]:
    """The same file under /lib and /usr/lib: dpkg knows it under the path its package ships."""
    cands = [path, os.path.realpath(path)]
    for p in list(cands):
        if p.startswith("/usr/"):
            cands.append(p[4:])
        else:
            cands.append("/usr" + p)
    return list(dict.fromkeys(cands))


def _dpkg_owners(paths: Iterable[str]) -> dict[str, str]:
    """Resolved path -> Debian package, in one ``dpkg-query -S`` call."""
    variants = {p: _usrmerge_variants(p) for p in paths}
    queries = sorted({v for vs in variants.values() for v in vs})
    if not queries:
        return {}
    proc = subprocess.run(["dpkg-query", "-S", *queries], capture_output=True, text=True, check=False)
    owner_of: dict[str, str] = {}
    for line in proc.stdout.splitlines():
        if line.startswith("diversion by") or ": " not in line:
            continue
        pkgs, _, path = line.rpartition(": ")
        owner_of[path.strip()] = pkgs.split(",")[0].strip().split(":")[0]
    out = {}
    for p, vs in variants.items():
        for v in vs:
            if v in owner_of:
                out[p] = owner_of[v]
                break
    return out


def scan_site_packages(roots: Sequence[Path] | None = None) -> LinkScan:
    """Run ``ldd`` on every ELF shared object under ``roots`` (default: this interpreter's
    site-packages) and map the libraries resolved outside them to Debian packages.

    Raises ``FileNotFoundError`` when ``ldd`` is not available (not a glibc system).
    """
    t0 = time.perf_counter()
    roots = tuple(Path(r).resolve() for r in (roots if roots is not None else site_packages_dirs()))
    if shutil.which("ldd") is None:
        raise FileNotFoundError("ldd is not available: the system-library check needs a glibc Linux")
    files = _shared_objects(roots)
    dist_of = _distribution_of_files(roots)
    uses: list[LibraryUse] = []
    for i in range(0, len(files), _LDD_BATCH):
        chunk = [str(f) for f in files[i:i + _LDD_BATCH]]
        # ldd exits non-zero when one file is not dynamic; its output is still complete.
        proc = subprocess.run(["ldd", *chunk], capture_output=True, text=True, check=False)
        for f, deps in parse_ldd(proc.stdout, chunk).items():
            fp = Path(f)
            root = next(r for r in roots if fp.is_relative_to(r))
            rel = str(fp.relative_to(root))
            dist = dist_of.get(fp, "unknown")
            for soname, resolved in deps:
                if resolved is not None and any(Path(os.path.normpath(resolved)).is_relative_to(r) for r in roots):
                    continue  # bundled by a wheel: not a system library
                uses.append(LibraryUse(soname, resolved, rel, dist))
    has_dpkg = shutil.which("dpkg-query") is not None
    owners = _dpkg_owners({u.resolved for u in uses if u.resolved}) if has_dpkg else {}
    return LinkScan(
        site_packages=tuple(str(r) for r in roots),
        n_files=len(files),
        uses=tuple(uses),
        owners=tuple(sorted(owners.items())),
        bundled=frozenset(f.name for f in files),
        dpkg=has_dpkg,
        seconds=time.perf_counter() - t0,
    )


def _never_loaded(use: LibraryUse) -> str | None:
    for pattern, soname, why in NEVER_LOADED:
        if use.soname == soname and fnmatch.fnmatch(use.needed_by, pattern):
            return why
    return None


def check_system_libraries(
    scan: LinkScan,
    install_list: frozenset[str] | None,
    base_list: frozenset[str] | None,
) -> SystemLibCheck:
    """Compare a scan with the install list and the base image's list (pure: no process runs).

    With both lists None only "not-found" is reported (``clutt3r doctor`` outside a checkout).
    A library resolved under this Python's own prefix (libpython of a non-Debian Python) counts
    as provided.
    """
    lists = install_list is not None and base_list is not None
    provided = (install_list or frozenset()) | (base_list or frozenset())
    groups: dict[tuple[str, str], list[LibraryUse]] = {}
    pkg_of: dict[tuple[str, str], tuple[str | None, bool]] = {}
    allowed: dict[str, str] = {}
    packages: set[str] = set()
    prefixes = tuple(os.path.realpath(p) for p in {sys.base_prefix, sys.prefix})
    for u in scan.uses:
        if u.resolved is None:
            why = BUNDLED_REASON if u.soname in scan.bundled else _never_loaded(u)
            if why is not None:
                allowed.setdefault(u.soname, why)
                continue
            key = ("not-found", u.soname)
            pkg_of[key] = (probable_package(u.soname), True)
        else:
            pkg = scan.owner(u.resolved)
            if pkg is not None:
                packages.add(pkg)
            if not scan.dpkg:
                continue  # no mapping to judge by
            if pkg is None:
                if os.path.realpath(u.resolved).startswith(prefixes):
                    continue
                key = ("unowned", u.soname)
                pkg_of[key] = (None, False)
            elif lists and pkg not in provided:
                key = ("unlisted", u.soname)
                pkg_of[key] = (pkg, False)
            else:
                continue
        groups.setdefault(key, []).append(u)
    problems = tuple(
        SystemLibProblem(
            kind=kind,  # type: ignore[arg-type]
            soname=soname,
            package=pkg_of[kind, soname][0],
            package_is_guess=pkg_of[kind, soname][1],
            needed_by=tuple(sorted({u.needed_by for u in us})),
            distributions=tuple(sorted({u.distribution for u in us})),
        )
        for (kind, soname), us in sorted(groups.items())
    )
    return SystemLibCheck(scan, problems, tuple(sorted(allowed.items())), tuple(sorted(packages)), lists)
