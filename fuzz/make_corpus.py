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

# LAS/LAZ: real small files of several versions and point formats.
for rel in ["las_format_samples/simple.las", "las_format_samples/simple.laz",
            "las_format_samples/test1_4.las", "las_format_samples/extrabytes.las",
            "autzen_lidar_ortho/autzen-utm.las"]:
    out("las", os.path.basename(rel), read(DATA, rel))

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
