"""Compares two folders captured by `.ci/outputs.sh capture`: exit 0 when every output is the same.

Text, CSV and JSON files must be byte-identical once the fields that change from run to run are masked:
durations printed by the commands ("in 3.2 s", "3.2 s elapsed", "trials/s"), and the provenance keys
(`created`, `started`, `finished`, `elapsed_s`, `commit`, `version`, host and thread counts).
Parquet files must hold the same schema and every column bit-identical (floats compared as their
int64 bit patterns, so NaN payloads and -0.0 count), and the same key-value metadata apart from the
provenance keys above. Usage: python3 .ci/compare_outputs.py OLD NEW
"""
import json
import pathlib
import re
import sys

import pyarrow.parquet as pq

VOLATILE_KEYS = {"created", "started", "finished", "elapsed_s", "commit", "git_commit", "gfcal:git_commit",
                 "version", "gfcal_version",
                 "host", "threads", "time", "wall_s", "seconds", "trials_per_s", "written"}
# Durations and rates in printed text: "... in 12.3 s", "12.3 s", "(4,577 trials/s)", ISO times.
TEXT_MASKS = [
    (re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z?"), "<time>"),
    (re.compile(r"[0-9][0-9,]*(\.[0-9]+)?\s*(ms|s|min)\b"), "<duration>"),
    (re.compile(r"[0-9][0-9,]*(\.[0-9]+)?\s*trials/s"), "<rate>"),
    (re.compile(r"commit [0-9a-f]{7,40}(-dirty)?"), "commit <c>"),
]


def mask_json(value):
    if isinstance(value, dict):
        return {k: ("<masked>" if k in VOLATILE_KEYS else mask_json(v)) for k, v in value.items()}
    if isinstance(value, list):
        return [mask_json(v) for v in value]
    return value


def mask_text(text):
    for pattern, repl in TEXT_MASKS:
        text = pattern.sub(repl, text)
    return text


def same_json_text(a, b):
    try:
        return mask_json(json.loads(a)) == mask_json(json.loads(b))
    except json.JSONDecodeError:
        return mask_text(a) == mask_text(b)


def parquet_diff(a, b):
    ta, tb = pq.read_table(a), pq.read_table(b)
    if ta.schema.remove_metadata() != tb.schema.remove_metadata():
        return "schema differs"
    if ta.num_rows != tb.num_rows:
        return f"rows {ta.num_rows} != {tb.num_rows}"
    for name in ta.column_names:
        ca, cb = ta.column(name).combine_chunks(), tb.column(name).combine_chunks()
        if ca.null_count != cb.null_count:
            return f"column {name}: nulls differ"
        if str(ca.type) in ("double", "float"):
            import numpy as np
            va = ca.to_numpy(zero_copy_only=False).view(np.int64 if str(ca.type) == "double" else np.int32)
            vb = cb.to_numpy(zero_copy_only=False).view(va.dtype)
            if not (va == vb).all():
                i = int((va != vb).argmax())
                return f"column {name}: first difference at row {i}"
        elif not ca.equals(cb):
            return f"column {name} differs"
    ma = {k: v for k, v in (ta.schema.metadata or {}).items()}
    mb = {k: v for k, v in (tb.schema.metadata or {}).items()}
    if set(ma) != set(mb):
        return "metadata keys differ"
    for key in ma:
        if key.decode() in VOLATILE_KEYS:
            continue
        if not same_json_text(ma[key].decode(), mb[key].decode()):
            return f"metadata {key.decode()} differs"
    return None


def captured_into(folder):
    """The folder the outputs were written into (the capture records it; outputs name it)."""
    mark = folder / ".captured_into"
    return mark.read_text().strip() if mark.exists() else str(folder)


def main(old, new):
    old, new = pathlib.Path(old), pathlib.Path(new)
    where_old, where_new = captured_into(old), captured_into(new)
    files_old = {p.relative_to(old) for p in old.rglob("*") if p.is_file() and p.name != ".captured_into"}
    files_new = {p.relative_to(new) for p in new.rglob("*") if p.is_file() and p.name != ".captured_into"}
    problems = [f"only in {old}: {p}" for p in sorted(files_old - files_new)]
    problems += [f"only in {new}: {p}" for p in sorted(files_new - files_old)]
    for rel in sorted(files_old & files_new):
        a, b = old / rel, new / rel
        if rel.suffix == ".parquet":
            why = parquet_diff(a, b)
        else:
            ta, tb = a.read_bytes(), b.read_bytes()
            if ta == tb:
                why = None
            elif rel.suffix in (".json", ".txt", ".csv", ".md", ".html", ".svg"):
                # The outputs name the folder they were captured into.
                da, db = ta.decode().replace(where_old, "<dir>"), tb.decode().replace(where_new, "<dir>")
                why = None if same_json_text(da, db) else "content differs"
            else:
                why = "bytes differ"
        if why:
            problems.append(f"{rel}: {why}")
    for line in problems:
        print(line)
    print(f"compared {len(files_old & files_new)} files: {'identical' if not problems else f'{len(problems)} differences'}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
