#!/usr/bin/env python3
"""Lists the longest functions of C++ sources (lines from the opening brace's
line to the closing brace), for the rule "no function in client/, server/ or
proto/ over 100 lines" (docs/performance.md, "Code size").

usage: scripts/function_lengths.py [--max N] [--top K] DIR_OR_FILE...
Exit status 1 when a function is longer than --max (when given), 2 for bad
arguments. The scan is lexical: comments and string literals are skipped, a
function is a brace block opened after a ')' (optionally followed by const,
noexcept, override, an initialiser list or a trailing return type) that is not
a control statement (if, for, while, switch, catch) or a lambda; a function
nested in a class body counts on its own. Lambdas count toward the function
that contains them."""
import argparse, os, re, sys

CONTROL = {"if", "for", "while", "switch", "catch", "do", "else", "return"}

def strip(src):
    out, i, n = [], 0, len(src)
    while i < n:
        c = src[i]
        if src.startswith("//", i):
            j = src.find("\n", i)
            j = n if j < 0 else j
            i = j
        elif src.startswith("/*", i):
            j = src.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
        elif c == '"' or c == "'":
            if c == '"' and i > 0 and src[i - 1] == "R":  # raw string R"d(...)d"
                m = re.match(r'"([^(\s]*)\(', src[i:])
                if m:
                    end = src.find(")" + m.group(1) + '"', i)
                    end = n if end < 0 else end + len(m.group(1)) + 2
                    out.append(re.sub(r"[^\n]", " ", src[i:end]))
                    i = end
                    continue
            j = i + 1
            while j < n and src[j] != c:
                j += 2 if src[j] == "\\" else 1
            out.append(" " * (j + 1 - i))
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)

def functions(path):
    src = strip(open(path, encoding="utf-8", errors="replace").read())
    res, stack = [], []  # stack of (kind, name, start_line)
    line = 1
    for i, c in enumerate(src):
        if c == "\n":
            line += 1
        elif c == "{":
            head = src[max(0, i - 400):i]
            kind, name = "block", ""
            in_fn = any(k == "fn" for k, _, _ in stack)
            m = re.search(r"([A-Za-z_~][\w:<>~]*)\s*\(([^()]|\([^()]*\))*\)\s*(const|noexcept|override|final|mutable|->\s*[\w:<>&*\s]+|\s)*"
                          r"(:\s*[^;{}]*)?$", head)
            if m and not in_fn:
                nm = m.group(1).split("::")[-1]
                if nm not in CONTROL and not re.search(r"\]\s*\([^()]*\)\s*(mutable\s*)?(->[^{]*)?$", head):
                    kind, name = "fn", m.group(1)
            stack.append((kind, name, line))
        elif c == "}" and stack:
            kind, name, start = stack.pop()
            if kind == "fn":
                res.append((line - start + 1, name, path, start))
    return res

def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--max", type=int, default=0, help="fail (exit 1) when a function is longer")
    ap.add_argument("--top", type=int, default=10, help="how many of the longest to list (default 10)")
    a = ap.parse_args()
    files = []
    for p in a.paths:
        if os.path.isdir(p):
            for root, _, names in os.walk(p):
                files += [os.path.join(root, f) for f in names if f.endswith((".cpp", ".h"))]
        elif os.path.isfile(p):
            files.append(p)
        else:
            print(f"function_lengths: no such file or folder: {p}", file=sys.stderr)
            return 2
    allf = sorted((f for p in sorted(files) for f in functions(p)), reverse=True)
    for n, name, path, start in allf[: a.top]:
        print(f"{n:5d}  {path}:{start}  {name}")
    over = [f for f in allf if a.max and f[0] > a.max]
    if over:
        print(f"function_lengths: {len(over)} function(s) over {a.max} lines", file=sys.stderr)
        return 1
    return 0

if __name__ == "__main__":
    sys.exit(main())
