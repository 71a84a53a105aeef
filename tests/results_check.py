#!/usr/bin/python3
"""scripts/results.py --check fails on a hand edit (issue 35, item 4), on copies of the docs.

    tests/results_check.py SOURCE_DIR WORK_DIR

Copies README.md, docs/RESULTS.md and docs/results/results.json into WORK_DIR and checks
that --check passes on the copies as they are, then fails, naming the file, the line and
the key, when: a marked inline number is edited; a cell of a generated table is edited; a
number the README states as measured loses its marker; a marker names a key that
results.json does not hold; a value's closing marker is deleted. And that --render puts
the generated number back, and that --reuse refuses outputs made by a build of
uncommitted changes, by an unknown commit or with no commit recorded.
"""
import pathlib
import re
import shutil
import subprocess
import sys

FILES = ["README.md", "docs/RESULTS.md", "docs/results/results.json"]
INLINE = re.compile(r"<!-- r:([A-Za-z0-9_.:@+-]+) -->([^<\n]*)<!-- /r -->")


def main():
    source, work = pathlib.Path(sys.argv[1]).resolve(), pathlib.Path(sys.argv[2]).resolve()
    script = source / "scripts" / "results.py"
    failures = []

    def fresh():
        if work.exists():
            shutil.rmtree(work)
        for rel in FILES:
            (work / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(source / rel, work / rel)

    def run(*extra):
        return subprocess.run([sys.executable, str(script), "--root", str(work), *extra],
                              capture_output=True, text=True)

    def expect(name, code, *needles, result=None):
        result = result or run("--check")
        problems = []
        if result.returncode != code:
            problems.append(f"exit {result.returncode}, expected {code}")
        for needle in needles:
            if needle not in result.stderr:
                problems.append(f"stderr does not contain '{needle}'")
        if problems:
            failures.append(f"{name}: {'; '.join(problems)}\n--- stderr:\n{result.stderr}")
        else:
            print(f"ok: {name}")

    def edit(rel, transform):
        path = work / rel
        text = path.read_text()
        new, line = transform(text)
        assert new != text, f"{rel}: the edit changed nothing"
        path.write_text(new)
        return line

    def line_of(text, pos):
        return text.count("\n", 0, pos) + 1

    fresh()
    expect("the docs as committed", 0)

    # 1. a marked number in the README edited by hand
    def bump_first_inline(text):
        m = INLINE.search(text)
        assert m, "README.md has no marked number"
        value = m.group(2)
        digit = next(i for i, ch in enumerate(value) if ch.isdigit())
        changed = value[:digit] + str((int(value[digit]) + 1) % 10) + value[digit + 1:]
        bump_first_inline.key = m.group(1)
        return text[:m.start(2)] + changed + text[m.end(2):], line_of(text, m.start())

    line = edit("README.md", bump_first_inline)
    expect("an edited marked number", 1, f"README.md:{line}: value r:{bump_first_inline.key} is")
    expect("--render puts it back", 0, result=run("--render"))
    expect("after --render", 0)

    # 2. a cell of a generated table in RESULTS edited by hand
    fresh()

    def edit_table_cell(text):
        start = text.index("<!-- results:table ")
        name = text[start:].split()[2]
        row = text.index("\n| ", text.index("|---", start)) + 1  # first data row
        cell = re.search(r"\d", text[row:]).start() + row
        edit_table_cell.name = name
        return text[:cell] + str((int(text[cell]) + 1) % 10) + text[cell + 1:], line_of(text, cell)

    line = edit("docs/RESULTS.md", edit_table_cell)
    expect("an edited table cell", 1, f"docs/RESULTS.md:{line}: table '{edit_table_cell.name}' differs")

    # 3. a measured number of the README's headline with its marker removed
    fresh()

    def unmark(text):
        for m in INLINE.finditer(text):
            paragraph_start = text.rfind("\n\n", 0, m.start())
            paragraph_end = text.find("\n\n", m.end())
            if "docs/RESULTS.md" in text[paragraph_start:paragraph_end]:
                unmark.value = m.group(2)
                return text[:m.start()] + m.group(2) + text[m.end():], line_of(text, m.start())
        raise AssertionError("no marked number in a README paragraph citing docs/RESULTS.md")

    line = edit("README.md", unmark)
    expect("an unmarked measured number", 1, f"README.md:{line}: '{unmark.value}", "is stated as measured")

    # 4. a marker whose key results.json does not hold
    fresh()
    line = edit("docs/RESULTS.md", lambda t: (t.replace("<!-- r:", "<!-- r:no_such.", 1),
                                             line_of(t, t.index("<!-- r:"))))
    expect("an unknown key", 1, f"docs/RESULTS.md:{line}: unknown value 'no_such.")

    # 5. a value marker whose closing marker was deleted
    fresh()

    def drop_close(text):
        m = INLINE.search(text)
        return text[:m.end(2)] + text[m.end():], line_of(text, m.start())

    line = edit("README.md", drop_close)
    expect("a deleted closing marker", 1, f"README.md:{line}: a value marker without")

    # --reuse: outputs stand for the running tofu's only when made by a commit with its
    # product code (issue 56, item 4).
    sys.path.insert(0, str(script.parent))
    import results  # noqa: E402
    head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=source,
                          capture_output=True, text=True).stdout.strip()
    if head:
        for made_by, reusable in ((head, True), (None, False), (head + "-dirty", False),
                                  ("0000000000ff", False)):
            why_not = results.reuse_refusal(source, made_by, head)
            if (why_not is None) != reusable:
                failures.append(f"reuse of outputs made by {made_by} under {head}: "
                                f"{'refused: ' + why_not if why_not else 'accepted'}, expected "
                                f"{'accepted' if reusable else 'refused'}")

    if failures:
        print("\n".join(failures), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
