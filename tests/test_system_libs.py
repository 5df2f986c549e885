"""The wheels of .venv must need no Debian package that a fresh machine lacks and the scripts do
not install (issue 8: open3d-cpu links libusb-1.0.so.0, which the base image lacks).

ldd on every shared object of site-packages, dpkg -S on what resolves outside it, compared with
scripts/system-packages.txt (installed by scripts/_env.sh) and scripts/base-image-packages.txt.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from clutt3r_core.system_libs import (
    LibraryUse,
    LinkScan,
    check_system_libraries,
    parse_ldd,
    probable_package,
    read_package_list,
    scan_site_packages,
)

REPO = Path(__file__).resolve().parents[1]
INSTALL_LIST = REPO / "scripts" / "system-packages.txt"
BASE_LIST = REPO / "scripts" / "base-image-packages.txt"

debian_only = pytest.mark.skipif(
    shutil.which("dpkg-query") is None or shutil.which("ldd") is None,
    reason="not a Debian system (no dpkg-query/ldd): the check maps libraries to Debian packages",
)


@pytest.fixture(scope="module")
def scan() -> LinkScan:
    return scan_site_packages()  # about 3-6 s; nothing cached across runs


@debian_only
def test_wheels_need_only_listed_or_base_packages(scan: LinkScan) -> None:
    check = check_system_libraries(scan, read_package_list(INSTALL_LIST), read_package_list(BASE_LIST))
    assert scan.n_files > 50, f"only {scan.n_files} shared objects under {scan.site_packages}: wrong venv?"
    assert check.lists_checked
    assert not check.problems, (
        "system libraries the wheels need are not provided on a fresh machine; add the Debian package to "
        "scripts/system-packages.txt (with why), or allowlist a never-loaded one in "
        "clutt3r_core.system_libs.NEVER_LOADED:\n" + "\n".join(map(str, check.problems))
    )
    # The scan saw what it must see: open3d's libusb comes from the install list, libc from the image.
    assert "libusb-1.0-0" in check.packages and "libc6" in check.packages


@debian_only
def test_dropping_libusb_from_the_install_list_is_caught(scan: LinkScan) -> None:
    install = read_package_list(INSTALL_LIST)
    assert "libusb-1.0-0" in install
    check = check_system_libraries(scan, install - {"libusb-1.0-0"}, read_package_list(BASE_LIST))
    hits = [p for p in check.problems if p.soname == "libusb-1.0.so.0"]
    assert len(hits) == 1, check.problems
    p = hits[0]
    # Installed: dpkg names it ("unlisted"); not installed: ldd cannot find it ("not-found").
    assert p.package == "libusb-1.0-0" and p.kind in ("unlisted", "not-found")
    assert any(d.startswith("open3d") for d in p.distributions)
    assert any(f.startswith("open3d/") for f in p.needed_by)
    assert "libusb-1.0.so.0" in str(p) and "libusb-1.0-0" in str(p) and "open3d/" in str(p)


def test_base_list_says_how_it_was_made_and_lacks_what_the_image_lacks() -> None:
    header = "".join(line for line in BASE_LIST.read_text().splitlines(keepends=True) if line.startswith("#"))
    assert "installed-python.txt" in header and "grep -P '^apt" in header
    base = read_package_list(BASE_LIST)
    assert {"libc6", "libstdc++6", "zlib1g", "libgl1"} <= base
    assert not {"libusb-1.0-0", "chromium"} & base, "the base image has neither (issue 8)"
    assert not read_package_list(INSTALL_LIST) & base, "a package in both lists: drop it from system-packages.txt"


def test_install_list_entries_say_why() -> None:
    for line in INSTALL_LIST.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            assert "#" in line and len(line.split("#", 1)[1].strip()) > 10, f"no reason given: {line!r}"


def test_the_shell_step_installs_exactly_the_list() -> None:
    out = subprocess.run(["bash", "-c", "source scripts/_env.sh && system_packages"], cwd=REPO,
                         capture_output=True, text=True, check=True).stdout
    assert frozenset(out.split()) == read_package_list(INSTALL_LIST)


def test_parse_ldd_one_and_several_files() -> None:
    one = ("\tlinux-vdso.so.1 (0x00007ffd)\n\tlibusb-1.0.so.0 => not found\n"
           "\tlibc.so.6 => /lib/x86_64-linux-gnu/libc.so.6 (0x00007f)\n\t/lib64/ld-linux-x86-64.so.2 (0x7f)\n")
    assert parse_ldd(one, ["/a/x.so"]) == {
        "/a/x.so": [("libusb-1.0.so.0", None), ("libc.so.6", "/lib/x86_64-linux-gnu/libc.so.6")]}
    several = "/a/x.so:\n\tlibz.so.1 => /lib/libz.so.1 (0x1)\n/a/y.so:\n\tstatically linked\n/a/z.so:\n\tlibm.so.6 => not found\n"
    assert parse_ldd(several, ["/a/x.so", "/a/y.so", "/a/z.so"]) == {
        "/a/x.so": [("libz.so.1", "/lib/libz.so.1")], "/a/y.so": [], "/a/z.so": [("libm.so.6", None)]}


@pytest.mark.parametrize("soname, package", [
    ("libusb-1.0.so.0", "libusb-1.0-0"), ("libGL.so.1", "libgl1"), ("libstdc++.so.6", "libstdc++6"),
    ("libtbb.so.12", "libtbb12"), ("libxcb.so.1", "libxcb1"), ("libfoo.so", None),
])
def test_probable_package_follows_debian_naming(soname: str, package: str | None) -> None:
    assert probable_package(soname) == package


def _scan(*uses: LibraryUse, owners=(), bundled=frozenset()) -> LinkScan:
    return LinkScan(("/sp",), 3, uses, tuple(owners), frozenset(bundled), True, 0.0)


def test_check_classifies_each_case() -> None:
    uses = (
        LibraryUse("libusb-1.0.so.0", None, "open3d/libOpen3D.so.0.19", "open3d-cpu 0.19.0"),
        LibraryUse("libquadmath-x.so.0", None, "scipy.libs/libgfortran-y.so.5", "scipy 1.17.1"),
        LibraryUse("libtensorflow_framework.so.2", None, "open3d/open3d_tf_ops.so", "open3d-cpu 0.19.0"),
        LibraryUse("libc.so.6", "/lib/libc.so.6", "numpy/_core/x.so", "numpy 2.0"),
        LibraryUse("libfoo.so.3", "/lib/libfoo.so.3", "foo/_x.so", "foo 1.0"),
        LibraryUse("libbar.so.1", "/opt/bar/libbar.so.1", "bar/_x.so", "bar 1.0"),
    )
    scan = _scan(*uses, owners=[("/lib/libc.so.6", "libc6"), ("/lib/libfoo.so.3", "libfoo3")],
                 bundled={"libquadmath-x.so.0"})
    check = check_system_libraries(scan, frozenset({"libusb-1.0-0"}), frozenset({"libc6"}))
    kinds = {(p.kind, p.soname, p.package) for p in check.problems}
    assert kinds == {("not-found", "libusb-1.0.so.0", "libusb-1.0-0"), ("unlisted", "libfoo.so.3", "libfoo3"),
                     ("unowned", "libbar.so.1", None)}
    assert [p.soname for p in check.missing] == ["libusb-1.0.so.0"]
    assert {s for s, _ in check.allowed} == {"libquadmath-x.so.0", "libtensorflow_framework.so.2"}
    # Without lists (doctor outside a checkout) only what is absent now is reported.
    assert {p.kind for p in check_system_libraries(scan, None, None).problems} == {"not-found", "unowned"}
