#!/usr/bin/env python3
"""The README's first-edit figure (docs/img/first-edit.jpg) from what scripts/quickstart.sh leaves in
out/first-edit/: the photo, each target's edit and its truth, side by side. Needs Pillow.

    python3 scripts/first_edit_figure.py out/first-edit docs/img/first-edit.jpg
"""
import sys
from PIL import Image, ImageDraw, ImageFont
fe = sys.argv[1]; out = sys.argv[2]
cells = [("photo (teal plastic)", f"{fe}/photo.png")]
for t, name in [("carpaint-red-gloss", "red car paint"), ("wood-oak-varnished", "varnished oak")]:
    cells += [(f"edit: {name}", f"{fe}/{t}/edited.png"), (f"truth: {name}", f"{fe}/truth-{t}.png")]
side = 256; pad = 24
img = Image.new("RGB", (side * len(cells), side + pad), (30, 30, 30))
font = ImageFont.truetype(str(__import__("pathlib").Path(__file__).resolve().parents[1] / "assets/fonts/DejaVuSans.ttf"), 15)
d = ImageDraw.Draw(img)
for k, (label, path) in enumerate(cells):
    im = Image.open(path).convert("RGBA")
    if "edited" in path:
        im.putalpha(Image.open(f"{fe}/photo.png").convert("RGBA").getchannel("A"))
    im = im.resize((side, side))
    bg = Image.new("RGBA", im.size, (30, 30, 30, 255)); bg.alpha_composite(im)
    img.paste(bg.convert("RGB"), (k * side, pad))
    d.text((k * side + 6, 3), label, fill=(230, 230, 230), font=font)
img.save(out, quality=88) if out.endswith(".jpg") else img.save(out)
