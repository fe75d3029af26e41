#!/usr/bin/env python3
"""Builds fuzz/corpus/<target>/ from formats/ samples, small real files of the shared data
(< 200 KB; see corpus/SOURCE.txt) and a few hand-written files. Multi-file inputs
(COLMAP models, DCP packages) are joined as fuzz/src/lib.rs `members` splits them: per
member a little-endian u32 length, then its bytes. The corpus is committed, so this only
needs re-running to change the seeds:  python3 fuzz/make_corpus.py /path/to/shared/data
COLMAP binary seeds need pycolmap (the project venv) to convert the synthetic text model.
"""
import json, os, struct, subprocess, sys, tempfile, zlib

FUZZ = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(FUZZ)
DATA = sys.argv[1] if len(sys.argv) > 1 else "/work/shared/data"
FMT = os.path.join(ROOT, "formats")
STEMS = ["cameras", "images", "points3D", "rigs", "frames"]


def out(target, name, data):
    d = os.path.join(FUZZ, "corpus", target)
    os.makedirs(d, exist_ok=True)
    assert len(data) < 200_000, (target, name, len(data))
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def read(*p):
    with open(os.path.join(*p), "rb") as f:
        return f.read()


def join(parts):
    b = b""
    for p in parts:
        if p is not None:
            b += struct.pack("<I", len(p)) + p
    return b


def model(dir, ext, stems=STEMS):
    parts = [read(dir, f"{s}.{ext}") if os.path.exists(os.path.join(dir, f"{s}.{ext}")) else b"" for s in stems]
    # Trailing absent members are left out; absent members before present ones stay empty files.
    while parts and parts[-1] == b"" and not os.path.exists(os.path.join(dir, f"{stems[len(parts)-1]}.{ext}")):
        parts.pop()
    return join(parts)


# COLMAP text: the small real and synthetic models (3-file) and the synthetic one in the
# 5-file COLMAP 4 layout written by pycolmap.
for name in ["synthetic_from_blocksexchange_txt", "kapture_t265_txt"]:
    out("colmap_txt", name, model(os.path.join(FMT, "colmap", name), "txt", STEMS[:3]))
py = os.path.join(ROOT, ".venv/bin/python")
if not os.path.exists(py):
    py = "/work/main/.venv/bin/python"
with tempfile.TemporaryDirectory() as t:
    subprocess.run([py, "-c", f"""
import pycolmap, os
r = pycolmap.Reconstruction({os.path.join(FMT, 'colmap', 'synthetic_from_blocksexchange_txt')!r})
os.makedirs({t!r} + '/bin'); os.makedirs({t!r} + '/txt')
r.write_binary({t!r} + '/bin'); r.write_text({t!r} + '/txt')
"""], check=True)
    out("colmap_txt", "synthetic_colmap4_txt", model(os.path.join(t, "txt"), "txt"))
    out("colmap_bin", "synthetic_colmap4_bin", model(os.path.join(t, "bin"), "bin"))
    out("colmap_bin", "synthetic_3file_bin", model(os.path.join(t, "bin"), "bin", STEMS[:3]))
m4 = os.path.join(FMT, "colmap", "kapture_maupertuis_colmap4_bin")
# Real COLMAP 4 cameras, rigs and frames with empty images and points.
out("colmap_bin", "maupertuis_no_images",
    join([read(m4, "cameras.bin"), struct.pack("<Q", 0), struct.pack("<Q", 0), read(m4, "rigs.bin"), read(m4, "frames.bin")]))

# BlocksExchange XML.
be = os.path.join(FMT, "blocks-exchange")
out("blocks_exchange", "itwin_v3.2.xml", read(be, "itwin_reality-capture_Orientations_bulkphotos_v3.2.xml"))
out("blocks_exchange", "synthetic_historical_v2.1.xml",
    read(be, "synthetic_historical_with_dcp", "synthetic_historical_with_dcp.xml"))

# DCP: the sample manifest (its chips are built into the target), and a package of one
# chip that every measurement shares, its checksum left to the target.
dcp = os.path.join(FMT, "dcp", "sample.dcp")
manifest = read(dcp, "manifest.json")
out("dcp_manifest", "sample_manifest.json", manifest)
m = json.loads(manifest)
for p in m["points"]:
    for ms in p["measurements"]:
        ms["chip"]["file"] = "chips/chip.png"
m["files"] = {"chips/chip.png": "@CHIP_SHA256@"}
out("dcp_package", "sample_one_chip", join([json.dumps(m, indent=1).encode(), read(dcp, "chips", "p1_1.png")]))

# LAS/LAZ: real small files of several versions and point formats, cut to their first 40
# points (laspy, with lazrs for the LAZ copies): the decoders' cost is per point (a
# thousand points ran the target at ~150 inputs/s), and every header, VLR and point
# format is kept.
las_cut = subprocess.run([py, "-c", """
import laspy, io, sys, struct
out = {}
for path, laz in [("las_format_samples/simple.las", (False, True)), ("las_format_samples/test1_4.las", (False, True)),
                  ("las_format_samples/extrabytes.las", (False, True)), ("autzen_lidar_ortho/autzen-utm.las", (False,))]:
    las = laspy.read(sys.argv[1] + "/" + path)
    las.points = las.points[:40]
    for z in laz:
        b = io.BytesIO()
        las.write(b, do_compress=z)
        name = path.split("/")[-1].rsplit(".", 1)[0] + ("-40pts.laz" if z else "-40pts.las")
        sys.stdout.buffer.write(struct.pack("<I", len(name)) + name.encode() + struct.pack("<I", len(b.getvalue())) + b.getvalue())
""", DATA], check=True, capture_output=True).stdout
while las_cut:
    (n,) = struct.unpack("<I", las_cut[:4]); name = las_cut[4:4 + n].decode(); las_cut = las_cut[4 + n:]
    (n,) = struct.unpack("<I", las_cut[:4]); out("las", name, las_cut[4:4 + n]); las_cut = las_cut[4 + n:]

# PLY: hand-written ascii and binary little endian.
pts = [(500000.5, 4400000.25, 12.0), (500001.0, 4400002.0, 13.5), (500003.0, 4400001.0, 11.25)]
head = "ply\nformat {}\ncomment fuzz seed\nelement vertex 3\nproperty double x\nproperty double y\nproperty float z\nproperty uchar red\nend_header\n"
out("ply_points", "ascii.ply", (head.format("ascii 1.0") + "".join(f"{x} {y} {z} 7\n" for x, y, z in pts)).encode())
out("ply_points", "binary_le.ply", head.format("binary_little_endian 1.0").encode()
    + b"".join(struct.pack("<ddfB", x, y, z, 7) for x, y, z in pts))

# CSV/text XYZ: hand-written and real tables.
out("csv_points", "xyz_header.csv", b"X,Y,Z,intensity\n500000.5,4400000.25,12.0,7\n500001,4400002,13.5,8\n")
out("csv_points", "xyz_blanks.txt", b"# comment\n500000.5 4400000.25 12.0\n500001\t4400002\t13.5\n500003;4400001;11.25\n")

# OpenDroneMap GCP files: the hand-written sample and the real COPR subset (CC BY-SA 4.0).
out("odm_gcp", "sample_gcp_list.txt", read(FMT, "control-points", "sample_gcp_list.txt"))
out("odm_gcp", "copr_gcp_list_subset.txt", read(DATA, "copr_kap_2009/gcp_list_subset.txt"))

# Project TOML and camera JSON.
out("project_toml", "example.toml", read(FMT, "project", "example.toml"))
for f in sorted(os.listdir(os.path.join(FMT, "cameras"))):
    if f.endswith(".json"):
        out("camera_json", f, read(FMT, "cameras", f))

# Image headers: PNG (a DCP chip, a real figure), JPEG (a fiducial crop), TIFF (real and
# a hand-written 8x8 grey strip image).
out("image_header", "chip.png", read(dcp, "chips", "p1_1.png"))
def chunk(kind, body):
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
rows = b"".join(b"\x00" + bytes(2 * 16) for _ in range(16))
out("image_header", "grey16_16x16.png", b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 16, 16, 16, 0, 0, 0, 0))
    + chunk(b"tEXt", b"Comment\x00fuzz seed") + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))
out("image_header", "notch_L.jpg", read(DATA, "fiducial_templates_nagap_ee/nagap/notch/L.jpg"))
out("image_header", "notch_L.tif", read(DATA, "fiducial_templates_nagap_ee/ee/notch/L.tif"))
entries = [(256, 3, 1, 8), (257, 3, 1, 8), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1),
           (273, 4, 1, 8 + 2 + 12 * 9 + 4), (277, 3, 1, 1), (278, 3, 1, 8), (279, 4, 1, 64)]
ifd = struct.pack("<H", len(entries)) + b"".join(
    struct.pack("<HHI", t, ty, n) + (struct.pack("<HH", v, 0) if ty == 3 else struct.pack("<I", v))
    for t, ty, n, v in entries) + struct.pack("<I", 0)
out("image_header", "grey8x8.tif", b"II*\x00" + struct.pack("<I", 8) + ifd + bytes(range(64)))


# ---- Seeds of the targets added in issue 51 (fiducial_io, image_decode, task_files,
# project_check, and camera_json's film cameras with template marks).

def png(width, height, rows, bit_depth=8, colour=0):
    """A PNG of `rows` (bytes per row, without the filter byte)."""
    raw = b"".join(b"\x00" + r for r in rows)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth, colour, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def mark_hit(shape, x, y):
    """Whether (x, y) mm from a mark's centre is on it (as shape.rs `covers`)."""
    r = (x * x + y * y) ** 0.5
    if "dot_mm" in shape and r <= shape["dot_mm"] / 2:
        return True
    if "ring_mm" in shape:
        w = shape.get("ring_line_mm", shape.get("line_mm", 0))
        if shape["ring_mm"] / 2 - w <= r <= shape["ring_mm"] / 2:
            return True
    s, l = shape.get("size_mm", 0) / 2, shape.get("line_mm", 0) / 2
    t = shape["type"]
    if t == "cross":
        return (abs(x) <= s and abs(y) <= l) or (abs(y) <= s and abs(x) <= l)
    if t in ("circle", "dot"):
        return r <= s
    if t == "ring":
        return s - shape["line_mm"] <= r <= s
    return False


def tiff(width, height, rows, tile=None):
    """An uncompressed grey 8-bit little-endian TIFF of `rows`: strips of 8 rows, or
    `tile`² tiles (padded with zeros), as scanners and GDAL write them."""
    data, offsets, counts = b"", [], []
    if tile is None:
        for r0 in range(0, height, 8):
            offsets.append(len(data))
            data += b"".join(rows[r0:r0 + 8])
            counts.append(len(data) - offsets[-1])
    else:
        for t0 in range(0, height, tile):
            for c0 in range(0, width, tile):
                offsets.append(len(data))
                for r in range(t0, t0 + tile):
                    row = rows[r][c0:c0 + tile] if r < height else b""
                    data += row + bytes(tile - len(row))
                counts.append(len(data) - offsets[-1])
    n = len(offsets)
    start = 8 + len(data)
    chunk_tags = (322, 323, 324, 325) if tile else (None, 278, 273, 279)
    entries = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1)]
    if tile:
        entries += [(322, 4, 1, tile), (323, 4, 1, tile)]
    else:
        entries += [(278, 4, 1, 8)]
    entries += [(277, 3, 1, 1)]
    ifd_len = 2 + 12 * (len(entries) + 2) + 4
    arrays = struct.pack(f"<{n}I", *(start_of + 8 for start_of in offsets)) + struct.pack(f"<{n}I", *counts)
    entries += [(chunk_tags[2], 4, n, start + ifd_len if n > 1 else offsets[0] + 8),
                (chunk_tags[3], 4, n, start + ifd_len + 4 * n if n > 1 else counts[0])]
    entries.sort()
    ifd = struct.pack("<H", len(entries)) + b"".join(
        struct.pack("<HHI", t, ty, k) + (struct.pack("<HH", v, 0) if ty == 3 and k == 1 else struct.pack("<I", v))
        for t, ty, k, v in entries) + struct.pack("<I", 0)
    return b"II*\x00" + struct.pack("<I", start) + data + ifd + (arrays if n > 1 else b"")


def scan(cam, size, pixel_mm, marks=True, write=None):
    """A grey 8-bit scan of `cam`'s frame, `size`² pixels: a dark frame, a smooth
    photograph inside the format, bright marks (5 x 5 supersampled) drawn through a
    scanner affine (0.2 % scale difference, 0.15 % shear, 0.23 deg rotation, off-centre);
    a PNG, else written by `write(size, size, rows)`."""
    import math
    a = 0.004
    c, s_ = math.cos(a), math.sin(a)
    # pixel offset -> mm: rot * diag(p, -p) * [[1.002, 0.0015], [0, 0.9985]]
    m = [[pixel_mm * 1.002, pixel_mm * 0.0015], [0.0, -pixel_mm * 0.9985]]
    lin = [[c * m[0][0] - s_ * m[1][0], c * m[0][1] - s_ * m[1][1]],
           [s_ * m[0][0] + c * m[1][0], s_ * m[0][1] + c * m[1][1]]]
    ox, oy = size / 2 + 1.3, size / 2 - 0.7
    fw, fh = cam["format_mm"]

    def to_mm(px, py):
        dx, dy = px - ox, py - oy
        return lin[0][0] * dx + lin[0][1] * dy, lin[1][0] * dx + lin[1][1] * dy

    rows = []
    for row in range(size):
        line = bytearray()
        for col in range(size):
            x, y = to_mm(col + 0.5, row + 0.5)
            v = 30.0
            if abs(x) < fw / 2 - 1.5 and abs(y) < fh / 2 - 1.5:
                v = 120 + 50 * math.sin(x / 1.1) * math.cos(y / 1.7)
            if marks:
                for f in cam["fiducials"]:
                    dx, dy = x - f["x_mm"], y - f["y_mm"]
                    if abs(dx) > 2 or abs(dy) > 2:
                        continue
                    hit = 0
                    for sy in range(5):
                        for sx in range(5):
                            qx, qy = to_mm(col + (sx + 0.5) / 5, row + (sy + 0.5) / 5)
                            hit += mark_hit(f["shape"], qx - f["x_mm"], qy - f["y_mm"])
                    v += 170 * hit / 25
            line.append(max(0, min(255, int(v + ((col * 7 + row * 13) % 5) - 2))))
        rows.append(bytes(line))
    return (write or png)(size, size, rows)


MARK = {"type": "cross", "size_mm": 2.0, "line_mm": 0.25, "ring_mm": 1.6, "dot_mm": 0.4}
MINI = {
    "name": "fuzz mini camera (23 mm format, 5 marks)",
    "source": "fuzz/make_corpus.py: a small synthetic camera whose marks are ~17 pixels on a 200-pixel scan; the fifth mark (left, above the middle) leaves the layout no symmetry of the square",
    "focal_mm": 15.3, "principal_point_mm": [0.01, -0.02], "format_mm": [23.0, 23.0],
    "fiducials": [
        {"id": "1", "x_mm": -9.0, "y_mm": -9.0, "shape": MARK},
        {"id": "2", "x_mm": 9.0, "y_mm": 9.0, "shape": MARK},
        {"id": "3", "x_mm": -9.0, "y_mm": 9.0, "shape": MARK},
        {"id": "4", "x_mm": 9.0, "y_mm": -9.0, "shape": MARK},
        {"id": "5", "x_mm": -10.0, "y_mm": 3.0, "shape": {"type": "circle", "size_mm": 1.0}},
    ],
}
mini = json.dumps(MINI, indent=1).encode()
mini_scan = scan(MINI, 200, 0.115)
out("fiducial_io", "mini_200px", join([mini, mini_scan]))
out("fiducial_io", "mini_200px_given", join([mini, mini_scan, b"pixel_um=115 orientation=0 projective"]))
# The same marks as image templates (template.png: the cross drawn at 0.1 mm a pixel).
tpl_rows = [bytes(30 + int(170 * mark_hit(MARK, (c - 12) * 0.1, (12 - r) * 0.1)) for c in range(25)) for r in range(25)]
tpl = png(25, 25, tpl_rows)
mini_tpl = dict(MINI, name="fuzz mini camera, template marks")
mini_tpl["fiducials"] = [dict(f, shape={"type": "template", "file": "template.png", "pixel_mm": 0.1})
                         if f["id"] != "5" else f for f in MINI["fiducials"]]
out("fiducial_io", "mini_template_200px", join([json.dumps(mini_tpl, indent=1).encode(), mini_scan, b"", tpl]))
# A real camera definition on a 256-pixel scan of it (its marks are a few pixels there).
rc10 = json.loads(read(FMT, "cameras", "wild_rc10.json"))
out("fiducial_io", "wild_rc10_256px", join([read(FMT, "cameras", "wild_rc10.json"), scan(rc10, 256, 230 / 256)]))
# The same scans as uncompressed TIFFs, which are read by windows from the file (strips;
# tiles of 64 pixels, padded at the right and bottom).
out("fiducial_io", "mini_200px_strips_tif", join([mini, scan(MINI, 200, 0.115, write=tiff)]))
out("fiducial_io", "wild_rc10_256px_tiles_tif",
    join([read(FMT, "cameras", "wild_rc10.json"), scan(rc10, 240, 230 / 240, write=lambda w, h, r: tiff(w, h, r, 64))]))
out("camera_json", "mini_template.json", json.dumps(mini_tpl, indent=1).encode())

# Image decoding: the header seeds that decode quickly, and small images of the other
# layouts the decoders have (RGB, RGBA, grey+alpha, 16-bit RGB PNG; palette PNG; an
# interlaced PNG; JPEG baseline and progressive, grey and colour; TIFF uncompressed, LZW,
# Deflate, PackBits, tiled, 16-bit RGB), the JPEGs and TIFFs written by gdal_translate
# from a 32 x 32 crop of the real notch mark (a decoder's cost is per pixel: the whole
# 17 KB JPEG ran the target at ~200 inputs/s).
for name in ["chip.png", "grey16_16x16.png", "grey8x8.tif"]:
    out("image_decode", name, read(FUZZ, "corpus", "image_header", name))
out("image_decode", "rgb8_8x8.png", png(8, 8, [bytes((r * 30 + c * 3 + k * 50) % 256 for c in range(8) for k in range(3)) for r in range(8)], 8, 2))
out("image_decode", "rgba8_4x4.png", png(4, 4, [bytes((r + c * k) % 256 for c in range(4) for k in range(4)) for r in range(4)], 8, 6))
out("image_decode", "greyalpha8_4x4.png", png(4, 4, [bytes((r * c + k) % 256 for c in range(4) for k in range(2)) for r in range(4)], 8, 4))
out("image_decode", "rgb16_4x4.png", png(4, 4, [b"".join(struct.pack(">H", (r * 4000 + c * 900 + k * 300)) for c in range(4) for k in range(3)) for r in range(4)], 16, 2))
pal = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 4, 4, 8, 3, 0, 0, 0))
       + chunk(b"PLTE", bytes([0, 0, 0, 255, 0, 0, 0, 255, 0, 0, 0, 255]))
       + chunk(b"IDAT", zlib.compress(b"".join(b"\x00" + bytes((r + c) % 4 for c in range(4)) for r in range(4))))
       + chunk(b"IEND", b""))
out("image_decode", "palette_4x4.png", pal)
# Adam7 interlaced 8x8 grey: the seven passes, each row with filter byte 0.
passes = [(0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2)]
raw = b""
for x0, y0, dx, dy in passes:
    for y in range(y0, 8, dy):
        raw += b"\x00" + bytes((x * 32 + y * 4) % 256 for x in range(x0, 8, dx))
with tempfile.TemporaryDirectory() as t:
    notch = os.path.join(DATA, "fiducial_templates_nagap_ee/nagap/notch/L.jpg")
    rgb = os.path.join(t, "rgb.png")
    with open(rgb, "wb") as f:
        f.write(png(32, 32, [bytes((r * 8 + c * k * 3) % 256 for c in range(32) for k in range(1, 4)) for r in range(32)], 8, 2))
    for name, src, opts in [
        ("notch_32px.jpg", notch, ["-of", "JPEG"]),
        ("notch_32px_progressive.jpg", notch, ["-of", "JPEG", "-co", "PROGRESSIVE=ON"]),
        ("rgb_32px.jpg", rgb, ["-of", "JPEG", "-co", "QUALITY=60"]),
        ("notch_32px_lzw.tif", notch, ["-of", "GTiff", "-co", "COMPRESS=LZW"]),
        ("notch_32px_deflate.tif", notch, ["-of", "GTiff", "-co", "COMPRESS=DEFLATE", "-co", "PREDICTOR=2"]),
        ("notch_32px_packbits.tif", notch, ["-of", "GTiff", "-co", "COMPRESS=PACKBITS"]),
        ("notch_32px_tiled.tif", notch, ["-of", "GTiff", "-co", "TILED=YES", "-co", "BLOCKXSIZE=16", "-co", "BLOCKYSIZE=16"]),
        ("rgb16_32px.tif", rgb, ["-of", "GTiff", "-ot", "UInt16", "-scale", "0", "255", "0", "65535"]),
    ]:
        dst = os.path.join(t, name)
        subprocess.run(["gdal_translate", "-q", "-srcwin", "0", "0", "32", "32", *opts, src, dst], check=True)
        out("image_decode", name, read(dst))
out("image_decode", "interlaced_8x8.png", b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 1))
    + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))

# Project files through `run --check`: the example in its expected folder (an empty layout
# member: every path as the example expects it), with a user's folder as the output, with
# the digital epoch's camera missing; a project controlled by an orthophoto and DEM with
# an existing block as its reference epoch.
example = read(FMT, "project", "example.toml")
out("project_check", "example_expected", join([example]))
# CHECK_PATHS order: lidar, lidar/tile.las, checkpoints.csv, checkpoint_images.csv,
# reference images/camera/pos, digital images/camera/pos, film images/camera/strips,
# ortho/orthophoto.tif, ortho/dem.tif, at/blocks_exchange.xml, out. Entry 0 = expected,
# 1 absent, 2 file, 3 empty folder, 4 folder holding a file, 5 link to a file, 6 link
# loop, 7 dangling link, 8 FIFO, 9 folder a run made (its marker holding the content).
out("project_check", "example_output_is_a_users_folder", join([example, bytes([0] * 16 + [4]), b"thesis"]))
out("project_check", "example_output_made_by_a_run", join([example, bytes([0] * 16 + [9]), b'{"cloudcontrol_output": 1}']))
out("project_check", "example_output_empty", join([example, bytes([0] * 16 + [3]), b""]))
out("project_check", "example_camera_missing", join([example, bytes([0] * 8 + [1]), b""]))
out("project_check", "example_links_and_fifo", join([example, bytes([0, 5, 8, 7, 0, 6]), b"x"]))
ortho_block = b'''name = "ortho-block"
crs = "EPSG:4547"
output = "out"

[control]
orthophoto = "ortho/orthophoto.tif"
orthophoto_crs = "EPSG:4547"
orthophoto_date = "2018-07"
orthophoto_sigma_m = 0.2
dem = "ortho/dem.tif"
dem_sigma_m = 0.5

[reference]
name = "reference"
date = "2019-05-04"
photos = "epochs/reference/images"
block = { path = "at/blocks_exchange.xml", format = "blocks_exchange", lidar_check = false }

[[archive]]
name = "film-1985"
date = "1985"
photos = "epochs/film/images"
camera = "epochs/film/camera.json"
strips = "epochs/film/strips.csv"
scan_dpi = 1200

[thresholds]
reject_k = 2.5

[outputs]
film_pixel_um = 21.2
'''
out("project_check", "ortho_dem_block", join([ortho_block]))
