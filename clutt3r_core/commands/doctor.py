"""``clutt3r doctor``: print what this installation has and lacks (``clutt3r_core.doctor``)."""

from __future__ import annotations

import json as _json

from clutt3r_core.doctor import DoctorReport, diagnose

__all__ = ["doctor_command", "render"]


def render(report: DoctorReport, console=None) -> None:  # noqa: ANN001 (rich Console, imported lazily)
    """Print the report as rich tables."""
    from rich.console import Console
    from rich.markup import escape as e  # hints like clutt3r[extra] are not markup
    from rich.table import Table

    con = console or Console()
    con.print(f"[bold]Python[/] {report.python} ({report.executable}) on {report.platform}")

    t = Table(title="Packages", title_justify="left")
    t.add_column("package")
    t.add_column("distribution")
    t.add_column("version")
    for p in report.packages:
        t.add_row(p.label, p.distribution or "-", p.version or "[red]not installed[/]")
    con.print(t)

    s = report.system
    con.print("[bold]System libraries[/]")
    if s.check is None:
        con.print(f"  not checked: {s.skipped}")
    else:
        c = s.check
        con.print(f"  {c.scan.n_files} shared objects in {', '.join(c.scan.site_packages)} checked with ldd "
                  f"in {c.scan.seconds:.1f} s; Debian packages they use: {', '.join(c.packages) or '-'}")
        for prob in c.problems:
            colour = "red" if prob.kind == "not-found" else "yellow"
            con.print(f"  [{colour}]{prob.kind}[/]: {e(str(prob))}")
        by_reason: dict[str, list[str]] = {}
        for soname, why in c.allowed:
            by_reason.setdefault(why, []).append(soname)
        for why, sonames in by_reason.items():
            con.print(f"  [dim]fine although ldd cannot find {e(', '.join(sonames))}: {e(why)}[/]")
        if not c.lists_checked:
            con.print("  [dim](not a source checkout: scripts/system-packages.txt not compared)[/]")
    if s.not_installed:
        con.print(f"  [red]not installed[/] from scripts/system-packages.txt: {', '.join(s.not_installed)}")
    if s.fix_command:
        con.print(f"  [bold red]fix:[/] {s.fix_command}   (./scripts/demo.sh and ./scripts/test.sh do this)")
    elif s.check is not None:
        con.print("  [green]none missing[/]")

    b = report.browser
    chromium = e(b.chromium_version or b.chromium or "") or "[yellow]absent[/] (apt-get install chromium; ./scripts/test.sh does)"
    playwright = e(b.playwright or "") or "[yellow]absent[/] " + e("(pip install 'clutt3r[test]')")
    con.print(f"[bold]Browser tests[/] chromium: {chromium}; playwright: {playwright}")

    t = Table(title="Backends", title_justify="left")
    for col in ("kind", "name", "available", "to add it", "description"):
        t.add_column(col)
    kinds_with_backends = {line.kind for line in report.backends}
    for kind in report.kinds:
        if kind not in kinds_with_backends:
            t.add_row(kind, "-", "[yellow]none registered[/]", "", "no backend of this kind is installed")
    for line in report.backends:
        avail = "[green]yes[/]" + (" (default)" if line.is_default else "") if line.available else "[yellow]no[/]"
        t.add_row(line.kind, e(line.name), avail, e(line.hint), e(line.description))
    con.print(t)
    for err in report.plugin_errors:
        con.print(f"[red]plugin error:[/] {e(err)}")
    if report.missing_packages:
        con.print(f"[bold red]missing core packages:[/] {', '.join(report.missing_packages)} (pip install -e .)")
    con.print("[bold green]ok[/]: the core works here" if report.ok else "[bold red]not ok[/]: see above")


def doctor_command(json: bool = False, skip_libraries: bool = False) -> None:
    """Show versions, missing system libraries, chromium for the browser tests, and which backends
    are available (and which extra would add the others).

    Exit status 0 when the core works here, 1 when a required system library or core package is
    missing (the report names it and the command that installs it).

    Args:
        json: print the report as JSON instead of tables.
        skip_libraries: skip the ldd scan of site-packages (about 3 s).
    """
    report = diagnose(check_libraries=not skip_libraries)
    if json:
        print(_json.dumps(report.to_json(), indent=2))
    else:
        render(report)
    raise SystemExit(0 if report.ok else 1)
