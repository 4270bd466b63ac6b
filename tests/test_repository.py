"""The repository explains itself: nothing in it points at design files kept outside it, and the
documents' links to repository files resolve."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"

# Names of the design files and research notes that once lived beside the repository. Built from
# pieces so that this file does not match itself; matched case-sensitively, so docs/benchmarks.md
# is not BENCHMARKS plus ".md".
FORBIDDEN = tuple(a + b for a, b in (
    ("DESIGN", ".md"), ("BENCHMARKS", ".md"), ("STYLE", ".md"),
    ("../", "shared"), ("shared", "/notes"),
    ("numerics", ".md"), ("ecosystem", ".md"), ("hil-practice", ".md"), ("anchor-starscreen", ".md"),
))

# [text](target) or [text](target "title"); images too.
LINK = re.compile(r"\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
# A path in a code span that starts at a top-level folder of the repository: `stand/loop.py`.
TOP = ("sim", "stand", "drivers", "star_screen", "fixtures", "tests", "docker", "docs", ".ci")
CODE_PATH = re.compile(r"`((?:" + "|".join(re.escape(t) for t in TOP) + r")/[^`\s]*)`")


def tracked_text_files() -> list[Path]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tracked files are unknown")
    done = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z"], capture_output=True, timeout=60)
    if done.returncode != 0:
        pytest.skip(f"git ls-files failed: {done.stderr.decode(errors='replace').strip()}")
    files = []
    for name in done.stdout.decode().split("\0"):
        path = ROOT / name
        if not name or not path.is_file():
            continue
        data = path.read_bytes()
        if b"\0" in data[:8192]:
            continue  # binary (PNG, npz)
        try:
            data.decode("utf-8")
        except UnicodeDecodeError:
            continue
        files.append(path)
    return files


def test_the_forbidden_names_are_what_they_claim():
    # Guards the pieces above against a typo that would make the scan below vacuous.
    assert {"DESIGN", "BENCHMARKS", "STYLE"} <= {name.removesuffix(".md") for name in FORBIDDEN}
    assert sum(name.count("shared") for name in FORBIDDEN) == 2 and len(set(FORBIDDEN)) == 9
    assert not any(name in "see docs/benchmarks.md and docs/numerical_methods.md" for name in FORBIDDEN)


def test_no_tracked_file_points_outside_the_repository():
    files = tracked_text_files()
    assert any(p.name == "README.md" for p in files) and any(p.suffix == ".py" for p in files)
    hits = []
    for path in files:
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for name in FORBIDDEN:
                if name in line:
                    hits.append(f"{path.relative_to(ROOT)}:{lineno}: {name}")
    assert not hits, "these lines point at files outside the repository (write what is needed into docs/):\n" + \
        "\n".join(hits)


def slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(md: Path) -> set[str]:
    out, fenced = set(), False
    for line in md.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            out.add(slug(line.lstrip("#")))
    return out


def documents() -> list[Path]:
    return sorted(DOCS.glob("*.md")) + [ROOT / "README.md"]


def present(relative: Path) -> bool:
    """False for a path whose top-level folder this copy lacks (the CI image has no .ci/ or docker/)."""
    top = relative.parts[0] if relative.parts else ""
    return not top or (ROOT / top).exists() or len(relative.parts) == 1


def broken_links(md: Path) -> list[str]:
    text = md.read_text(encoding="utf-8")
    bad = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):
            continue  # http:, https:, mailto:
        path_part, _, fragment = target.partition("#")
        dest = (md.parent / path_part).resolve() if path_part else md
        if ROOT not in dest.parents and dest != ROOT:
            bad.append(f"{target} (outside the repository)")
        elif not present(dest.relative_to(ROOT)):
            continue
        elif not dest.exists():
            bad.append(f"{target} (no such file)")
        elif fragment and dest.suffix == ".md" and fragment not in anchors(dest):
            bad.append(f"{target} (no heading #{fragment})")
    for path in CODE_PATH.findall(text):
        if any(c in path for c in "<>*{}") or "..." in path:
            continue  # a pattern, not a file
        if present(Path(path)) and not (ROOT / path).exists():
            bad.append(f"`{path}` (no such file)")
    return bad


def test_documents_exist_and_the_index_lists_every_document():
    index = (DOCS / "README.md").read_text(encoding="utf-8")
    for name in ("architecture.md", "conventions.md", "public_surface.md", "benchmarks.md"):
        assert (DOCS / name).is_file(), name
    missing = [md.name for md in DOCS.glob("*.md") if md.name != "README.md" and f"]({md.name})" not in index]
    assert not missing, f"docs/README.md does not link {missing}"


@pytest.mark.parametrize("md", documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_links_in_documents_resolve(md):
    bad = broken_links(md)
    assert not bad, f"{md.relative_to(ROOT)} has links that do not resolve: {bad}"


def test_the_link_checker_catches_a_broken_link(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "stand").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# Exit codes\n")
    md = tmp_path / "docs" / "b.md"
    md.write_text("[ok](a.md#exit-codes) [gone](c.md) [anchor](a.md#nope) [web](https://example.org)\n"
                  "`stand/missing.py` `fixtures/<name>/` [up](../../x.md)\n")
    bad = broken_links(md)
    assert len(bad) == 4, bad
    assert any("c.md" in b for b in bad) and any("#nope" in b for b in bad)
    assert any("stand/missing.py" in b for b in bad) and any("outside" in b for b in bad)


def test_ci_runs_the_readme_test_command_character_for_character():
    readme = (ROOT / "README.md").read_text()
    ci = ROOT / ".ci" / "run"
    if not ci.exists():
        pytest.skip("no .ci/run in this copy")
    commands = [line[4:] for line in readme.splitlines() if line.startswith("    ") and "pytest" in line]
    assert commands, "the README has no indented test command"
    assert commands[0] in ci.read_text().splitlines()


def test_the_readme_lists_every_shipped_scenario_and_its_set_up_names_socat():
    from stand.scenario.files import shipped

    readme = (ROOT / "README.md").read_text()
    table = set(re.findall(r"^\| `([a-z0-9_]+)`(?: \(default\))? \|", readme, flags=re.M))
    assert set(shipped()) <= table, f"missing from the README's scenario table: {sorted(set(shipped()) - table)}"
    setup = readme.split("## What the default scenario does", 1)[0]
    assert "apt-get install socat" in setup


def test_the_readme_does_not_offer_scenario_to_the_cage_emulator(capsys):
    # `stand emulate cage --scenario S` is refused (the cage serves open loop only): the README must say so where it
    # offers --scenario to the emulators.
    from stand.cli import main

    readme = (ROOT / "README.md").read_text()
    emulate = readme.split("- `stand emulate KIND --port PORT`", 1)[1].split("\n- ", 1)[0]
    assert "not `cage`, which serves open loop only" in emulate
    assert main(["emulate", "cage", "--port", "tcp://127.0.0.1:0", "--scenario", "detumble_cage"]) == 2
    assert "open loop only" in capsys.readouterr().err


def test_benchmarks_md_lists_every_bench_stand_bench_runs():
    from stand.benches import BENCHES

    text = (DOCS / "benchmarks.md").read_text()
    listed = set(re.findall(r"^\| `stand bench ([a-z-]+)` \|", text, flags=re.M))
    assert listed == set(BENCHES), f"docs/benchmarks.md lists {sorted(listed)}, stand bench runs {sorted(BENCHES)}"
