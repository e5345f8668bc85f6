"""Writes the figures of every recording_K.html (inline SVG) to figures/recording_K_NAME.svg, so that
README.md can show them (standard library only)."""
import os, re, sys
d = sys.argv[1]
os.makedirs(f"{d}/figures", exist_ok=True)
for k in range(1, 7):
    html = open(f"{d}/recording_{k}.html").read()
    for name, svg in re.findall(r'<figure id="([^"]+)">\s*(<svg.*?</svg>)', html, re.S):
        with open(f"{d}/figures/recording_{k}_{name}.svg", "w") as f:
            f.write(svg + "\n")
