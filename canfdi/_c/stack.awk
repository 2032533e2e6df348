# The deepest call chains of an image, from gcc's -fcallgraph-info=su graphs (`make size` of
# a generated project): each function's own frame plus its deepest callee's chain, for each
# function named in `roots` (a space-separated list; a name matches its LTO clones too,
# name.constprop.0 and the like). Functions with no graph of their own (the C library's:
# memcpy, the soft-float helpers) are listed and counted as 0; recursion or a dynamic frame
# would leave the chain unbounded and is said so. Not the core.
function bare(t) { sub(/^[^:]*:/, "", t); return t }
function deepest(f,    i, d, best, c) {
    if (f in memo) return memo[f]
    if (f in busy) { cyclic[f] = 1; return 0 }
    busy[f] = 1; best = 0; via[f] = ""
    for (i = 1; i <= n_out[f]; i++) {
        c = out[f, i]; d = deepest(c)
        if (d > best || (d == best && via[f] == "")) { best = d; via[f] = c }
    }
    delete busy[f]
    if (!(f in bytes)) library[f] = 1
    return memo[f] = bytes[f] + best
}
/^node:/ {
    match($0, /title: "[^"]*"/); t = bare(substr($0, RSTART + 8, RLENGTH - 9))
    if (match($0, /[0-9]+ bytes/)) bytes[t] = substr($0, RSTART, RLENGTH) + 0
    if ($0 ~ /bytes \(dynamic/) dynamic[t] = 1
    known[t] = 1
}
/^edge:/ {
    match($0, /sourcename: "[^"]*"/); s = bare(substr($0, RSTART + 13, RLENGTH - 14))
    match($0, /targetname: "[^"]*"/); d = bare(substr($0, RSTART + 13, RLENGTH - 14))
    if (!((s, d) in seen)) { seen[s, d] = 1; out[s, ++n_out[s]] = d }
}
END {
    n = split(roots, r, " ")
    for (i = 1; i <= n; i++) {
        root = ""
        for (f in known) {
            if ((f == r[i] || index(f, r[i] ".") == 1) && (root == "" || f < root)) root = f
        }
        if (root == "") { printf "worst stack: no function %s in the call graph\n", r[i]; bad = 1; continue }
        w = deepest(root); chain = r[i]
        for (f = root; via[f] != ""; f = via[f]) { g = via[f]; sub(/\..*/, "", g); chain = chain " > " g }
        printf "worst stack %d bytes from %s (%s)\n", w, r[i], chain
    }
    x = ""; for (f in library) x = x " " f
    if (x != "") printf "  not counted (no call graph: the C library's):%s\n", x
    x = ""; for (f in cyclic) x = x " " f
    if (x != "") { printf "  recursion, unbounded:%s\n", x; bad = 1 }
    x = ""; for (f in dynamic) x = x " " f
    if (x != "") { printf "  dynamic frames, unbounded:%s\n", x; bad = 1 }
    exit bad
}
