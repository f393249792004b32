#!/usr/bin/env python3
"""The layering rules of src/ (docs/architecture.md, "Layers"), checked on the includes.

    python3 tests/layering.py SRC_DIR        exit 1 and one line per broken rule
    python3 tests/layering.py --self-test    the checker catches each kind of break

Rules:
  1. A folder includes only its own headers and those of folders in lower layers, so layers only
     point down, and folders of one layer (gp/ and pp/, say) never include each other.
  2. MPI (<mpi.h> or an MPI_ call) appears only in comm/.
  3. Every folder of src/ is in the table below and has a README.md.
"""
import os
import re
import sys
import tempfile

# Folder -> layer. Lower layers know nothing of higher ones.
LAYERS = {
    "core": 0,             # value types, math, configuration, file formats, render geometry
    "comm": 1,             # messages and the transport (the only MPI)
    "sim": 1,              # the simulated world
    "gp": 1,               # graphics-processor stages (pure)
    "pp": 1,               # pixel-processor stages (pure)
    "interface_board": 1,  # the USB board's wire format, driver and emulator
    "igtl": 1,             # the OpenIGTLink client
    "viewer": 1,           # the live viewer's server
    "calib": 1,            # probe calibration with an N-wire phantom
    "parallel": 2,         # schedules, partitionings, parallel settings
    "serial": 2,           # the single-process reference pipeline
    "ranks": 3,            # the GP and PP rank loops
    "host": 4,             # sources, acquisition, the one run loop and its two pipelines
    "outputs": 5,          # the run's outputs as sinks of the run loop
    "harness": 5,          # the partitioning benchmark's harness
    "app": 6,              # the command line
}

INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^>"]+)[>"]')
MPI_CALL = re.compile(r"\bMPI_[A-Z][A-Za-z_]*\b")
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


def check(src):
    problems = []
    folders = sorted(d for d in os.listdir(src) if os.path.isdir(os.path.join(src, d)))
    for d in folders:
        if d not in LAYERS:
            problems.append(f"src/{d}/: a folder the layering table of tests/layering.py does not know; give it a layer")
        if not os.path.isfile(os.path.join(src, d, "README.md")):
            problems.append(f"src/{d}/: no README.md saying what it holds and what it may include")
    for d in folders:
        if d not in LAYERS:
            continue
        for root, _, files in os.walk(os.path.join(src, d)):
            for name in sorted(files):
                if not name.endswith(SOURCE_EXT):
                    continue
                path = os.path.join(root, name)
                rel = os.path.relpath(path, os.path.dirname(src))
                in_block = False
                with open(path, encoding="utf-8", errors="replace") as f:
                    for n, line in enumerate(f, 1):
                        m = INCLUDE.match(line)
                        if m:
                            target = m.group(1)
                            if target == "mpi.h" and d != "comm":
                                problems.append(f"{rel}:{n}: includes <mpi.h>; only comm/ may see MPI")
                            top = target.split("/")[0]
                            if "/" in target and top in LAYERS and top != d and LAYERS[top] >= LAYERS[d]:
                                how = "the same layer" if LAYERS[top] == LAYERS[d] else "a higher layer"
                                problems.append(f"{rel}:{n}: {d}/ (layer {LAYERS[d]}) includes {target}, "
                                                f"of {how} ({top}/, layer {LAYERS[top]})")
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

        for d in ("core", "gp", "pp", "comm", "parallel"):
            write(f"{d}/README.md", "x\n")
        write("core/a.hpp", "#pragma once\n")
        write("gp/b.cpp", '#include "core/a.hpp"\n// MPI_Send in a comment is fine\nconst char* s = "MPI_Bcast(";\n')
        write("parallel/c.cpp", '#include "gp/b.hpp"\n#include "comm/t.hpp"\n')
        write("comm/t.cpp", "#include <mpi.h>\nvoid f() { MPI_Barrier(0); }\n")
        clean = check(src)
        if clean:
            print("self-test: a clean tree was refused:", *clean, sep="\n  ")
            ok = False
        breaks = {
            "gp/up.cpp": ('#include "parallel/c.hpp"\n', "includes parallel/c.hpp, of a higher layer"),
            "gp/side.cpp": ('#include "pp/r.hpp"\n', "includes pp/r.hpp, of the same layer"),
            "core/down.cpp": ('#include "gp/b.hpp"\n', "core/ (layer 0) includes gp/b.hpp"),
            "pp/mpi.cpp": ("#include <mpi.h>\n", "includes <mpi.h>; only comm/ may see MPI"),
            "parallel/call.cpp": ("void g() {\n  MPI_Barrier(MPI_COMM_WORLD);\n}\n", "MPI_Barrier outside comm/"),
            "newfolder/x.cpp": ("\n", "src/newfolder/: a folder the layering table"),
        }
        for rel, (text, want) in breaks.items():
            write(rel, text)
            found = check(src)
            if not any(want in p for p in found):
                print(f"self-test: adding {rel} was not caught as '{want}'; found:", *found, sep="\n  ")
                ok = False
            os.remove(os.path.join(src, rel))
        write("serial/README.md", "x\n")
        os.remove(os.path.join(src, "serial/README.md"))
        write("serial/p.cpp", '#include "gp/b.hpp"\n')
        if not any("src/serial/: no README.md" in p for p in check(src)):
            print("self-test: a folder without a README was not caught")
            ok = False
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
