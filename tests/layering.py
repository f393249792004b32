#!/usr/bin/env python3
"""The rules of src/, checked on the includes. The rules live in one place: each folder's README.md.

    python3 tests/layering.py SRC_DIR        exit 1 and one line per broken rule
    python3 tests/layering.py --self-test    the checker catches each kind of break

Rules:
  1. Every folder of src/ has a README.md with a sentence "May include: a/, b/." (or "every folder
     of src/", or "nothing of src/ but itself"), and includes only its own headers and those of the
     folders that sentence names.
  2. What the READMEs allow has no cycle, so layers only point down.
  3. MPI (<mpi.h> or an MPI_ call) appears only in comm/.
  4. No source file is over 600 lines; in host/ and app/, none is over 400.
  5. A README may split its folder into sides with a sentence "Sides: the X side (a, b, c) is
     included by no file of the Y side": the files named a, b, c (any extension) may be included
     only by each other.
"""
import os
import re
import sys
import tempfile

MAX_LINES = 600
MAX_LINES_BY_FOLDER = {"host": 400, "app": 400}  # the loop and the command line stay thin

INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^>"]+)[>"]')
MPI_CALL = re.compile(r"\bMPI_[A-Z][A-Za-z_]*\b")
MAY_INCLUDE = re.compile(r"May include:\s*(.*?)(?:\.\s|\.$)", re.S)
SIDES = re.compile(r"Sides:\s*the (\w+) side \(([^)]*)\) is\s+included by no file of the (\w+) side", re.S)
SOURCE_EXT = (".hpp", ".cpp", ".h", ".cc", ".inl")


def strip_comments_and_strings(line, in_block):
    """The code of one line, without comments and string literals; tracks /* */ across lines."""
    out, i = [], 0
    while i < len(line):
        if in_block:
            end = line.find("*/", i)
            if end < 0:
                return "".join(out), True
            i, in_block = end + 2, False
        elif line.startswith("//", i):
            break
        elif line.startswith("/*", i):
            in_block, i = True, i + 2
        elif line[i] == '"':
            end = i + 1
            while end < len(line) and line[end] != '"':
                end += 2 if line[end] == "\\" else 1
            out.append('""')
            i = end + 1
        else:
            out.append(line[i])
            i += 1
    return "".join(out), in_block


def allowed(src, folders):
    """Folder -> the set of folders its README lets it include (None: no such sentence), and the problems."""
    rules, problems = {}, []
    for d in folders:
        readme = os.path.join(src, d, "README.md")
        if not os.path.isfile(readme):
            problems.append(f"src/{d}/: no README.md saying what it holds and what it may include")
            rules[d] = None
            continue
        with open(readme, encoding="utf-8") as f:
            m = MAY_INCLUDE.search(f.read())
        if not m:
            problems.append(f"src/{d}/README.md: no \"May include: ...\" sentence")
            rules[d] = None
            continue
        sentence = m.group(1)
        if "every folder" in sentence:
            rules[d] = set(folders) - {d}
            continue
        if sentence.startswith("nothing of src/"):
            rules[d] = set()
            continue
        names = set(re.findall(r"\b([a-z_]+)/", sentence))
        for n in sorted(names - set(folders)):
            problems.append(f"src/{d}/README.md: may include {n}/, which is no folder of src/")
        rules[d] = names & set(folders)
    return rules, problems


def sides(src, d):
    """The stems of the files of d/ that only each other may include, and the sides' names (or None)."""
    readme = os.path.join(src, d, "README.md")
    if not os.path.isfile(readme):
        return None
    with open(readme, encoding="utf-8") as f:
        m = SIDES.search(f.read())
    if not m:
        return None
    stems = {s.strip() for s in m.group(2).split(",") if s.strip()}
    return stems, m.group(1), m.group(3)


def stem(name):
    return name.split(".")[0]


def cycles(rules):
    """One line per cycle in what the READMEs allow (each found once, from its first folder)."""
    found, state = [], {}

    def visit(d, path):
        state[d] = 1
        for n in sorted(rules.get(d) or ()):
            if state.get(n) == 1:
                found.append(" -> ".join(path[path.index(n):] + [n]) if n in path else f"{d} -> {n}")
            elif n not in state:
                visit(n, path + [n])
        state[d] = 2

    for d in sorted(rules):
        if d not in state:
            visit(d, [d])
    return found


def check(src):
    folders = sorted(d for d in os.listdir(src) if os.path.isdir(os.path.join(src, d)))
    rules, problems = allowed(src, folders)
    for c in cycles(rules):
        problems.append(f"the READMEs' \"May include\" lists have a cycle: {c}")
    for d in folders:
        limit = MAX_LINES_BY_FOLDER.get(d, MAX_LINES)
        split = sides(src, d)
        for root, _, files in os.walk(os.path.join(src, d)):
            for name in sorted(files):
                if not name.endswith(SOURCE_EXT):
                    continue
                path = os.path.join(root, name)
                rel = os.path.relpath(path, os.path.dirname(src))
                in_block = False
                with open(path, encoding="utf-8", errors="replace") as f:
                    lines = f.readlines()
                if len(lines) > limit:
                    problems.append(f"{rel}: {len(lines)} lines, over {d}/'s limit of {limit}")
                for n, line in enumerate(lines, 1):
                    m = INCLUDE.match(line)
                    if m:
                        target = m.group(1)
                        if target == "mpi.h" and d != "comm":
                            problems.append(f"{rel}:{n}: includes <mpi.h>; only comm/ may see MPI")
                        top = target.split("/")[0]
                        if split and top == d and stem(target.split("/")[-1]) in split[0] \
                                and stem(name) not in split[0]:
                            problems.append(f"{rel}:{n}: the {split[2]} side includes {target}, of the "
                                            f"{split[1]} side (src/{d}/README.md)")
                        if "/" in target and top in rules and top != d and rules[d] is not None \
                                and top not in rules[d]:
                            problems.append(f"{rel}:{n}: {d}/ includes {target}, but src/{d}/README.md does not "
                                            f"let it include {top}/")
                        continue
                    code, in_block = strip_comments_and_strings(line, in_block)
                    if d != "comm" and MPI_CALL.search(code):
                        problems.append(f"{rel}:{n}: {MPI_CALL.search(code).group(0)} outside comm/")
    return problems


def self_test():
    """A tree that follows the rules passes; each kind of break is named."""
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "src")

        def write(rel, text):
            p = os.path.join(src, rel)
            os.makedirs(os.path.dirname(p), exist_ok=True)
            with open(p, "w") as f:
                f.write(text)

        write("core/README.md", "Core.\n\nMay include: nothing of src/ but itself.\n")
        write("gp/README.md", "GP.\n\nMay include: core/. Never pp/.\n")
        write("pp/README.md", "PP.\n\nMay include: core/.\n")
        write("comm/README.md", "Comm.\n\nMay include: core/.\n")
        write("parallel/README.md", "Parallel.\n\nMay include: core/, comm/, gp/ (its\nstages), pp/.\n")
        write("app/README.md", "App.\n\nMay include: every folder of src/.\n")
        write("render/README.md", "Render.\n\nSides: the PP side (cache, tiles) is\nincluded by no file of the GP "
              "side.\n\nMay include: core/.\n")
        write("render/cache.hpp", "#pragma once\n")
        write("render/tiles.cpp", '#include "render/cache.hpp"\n')
        write("render/shade.cpp", '#include "render/shade.hpp"\n')
        write("core/a.hpp", "#pragma once\n")
        write("gp/b.cpp", '#include "core/a.hpp"\n// MPI_Send in a comment is fine\nconst char* s = "MPI_Bcast(";\n')
        write("parallel/c.cpp", '#include "gp/b.hpp"\n#include "comm/t.hpp"\n')
        write("comm/t.cpp", "#include <mpi.h>\nvoid f() { MPI_Barrier(0); }\n")
        write("app/m.cpp", '#include "parallel/c.hpp"\n' + "int x;\n" * 390)
        clean = check(src)
        if clean:
            print("self-test: a clean tree was refused:", *clean, sep="\n  ")
            ok = False
        breaks = {
            "gp/up.cpp": ('#include "parallel/c.hpp"\n', "does not let it include parallel/"),
            "gp/side.cpp": ('#include "pp/r.hpp"\n', "does not let it include pp/"),
            "core/down.cpp": ('#include "gp/b.hpp"\n', "src/core/README.md does not let it include gp/"),
            "pp/mpi.cpp": ("#include <mpi.h>\n", "includes <mpi.h>; only comm/ may see MPI"),
            "parallel/call.cpp": ("void g() {\n  MPI_Barrier(MPI_COMM_WORLD);\n}\n", "MPI_Barrier outside comm/"),
            "newfolder/x.cpp": ("\n", "src/newfolder/: no README.md"),
            "render/sample.cpp": ('#include "render/cache.hpp"\n', "the GP side includes render/cache.hpp"),
            "gp/long.cpp": ("int y;\n" * 601, "601 lines, over gp/'s limit of 600"),
            "app/long.cpp": ("int y;\n" * 401, "401 lines, over app/'s limit of 400"),
            "pp/README.md": ("PP.\n\nMay include: core/, parallel/.\n", "have a cycle"),
            "comm/README.md": ("Comm, which includes what it likes.\n", "src/comm/README.md: no \"May include"),
        }
        for rel, (text, want) in breaks.items():
            path = os.path.join(src, rel)
            before = open(path).read() if os.path.exists(path) else None
            write(rel, text)
            found = check(src)
            if not any(want in p for p in found):
                print(f"self-test: writing {rel} was not caught as '{want}'; found:", *found, sep="\n  ")
                ok = False
            if before is None:
                os.remove(path)
            else:
                write(rel, before)
    print("layering self-test:", "every break caught" if ok else "FAILED")
    return 0 if ok else 1


def main():
    if len(sys.argv) == 2 and sys.argv[1] == "--self-test":
        return self_test()
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    problems = check(sys.argv[1])
    for p in problems:
        print(p)
    n = sum(1 for _, _, fs in os.walk(sys.argv[1]) for f in fs if f.endswith(SOURCE_EXT))
    print(f"layering: {n} files, {len(problems)} broken rules")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
