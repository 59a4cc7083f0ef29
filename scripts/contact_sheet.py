"""A contact sheet of rendered episodes: one row per GIF (`coadapt render --out X.gif`), its
first N frames side by side, scaled down. For a figure of how a policy moves (EXPERIMENTS.md).

usage: .venv-peers/bin/python scripts/contact_sheet.py OUT.png [--frames 10] [--scale 0.5] A.gif [B.gif ...]

Needs Pillow (matplotlib brings it: the `.venv-peers` the other plot scripts use has it).
"""
import sys

from PIL import Image


def frames(path, n):
    im = Image.open(path)
    out = []
    try:
        while len(out) < n:
            out.append(im.convert("RGB").copy())
            im.seek(im.tell() + 1)
    except EOFError:
        pass
    return out


def main():
    args = sys.argv[1:]
    opts = {"--frames": "10", "--scale": "0.5"}
    rest = []
    while args:
        a = args.pop(0)
        if a in opts:
            if not args:
                sys.exit(f"contact_sheet: {a} needs a value")
            opts[a] = args.pop(0)
        else:
            rest.append(a)
    if len(rest) < 2:
        sys.exit(__doc__)
    out, gifs = rest[0], rest[1:]
    n, scale = int(opts["--frames"]), float(opts["--scale"])
    rows = [frames(g, n) for g in gifs]
    if not all(rows):
        sys.exit("contact_sheet: a GIF without frames")
    w, h = rows[0][0].size
    sheet = Image.new("RGB", (w * n, h * len(rows)), "white")
    for j, row in enumerate(rows):
        for i, f in enumerate(row):
            sheet.paste(f, (i * w, j * h))
    sheet = sheet.resize((int(w * n * scale), int(h * len(rows) * scale)))
    sheet.save(out)
    print(f"contact_sheet: wrote {out} ({len(rows)} rows of {n} frames)")


if __name__ == "__main__":
    main()
