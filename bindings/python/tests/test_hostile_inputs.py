"""Hostile inputs through the Python binding and the C ABI (issue 17): small crafted files
whose counts, sizes or references claim far more than they hold are refused with the
documented status and a message naming the input and the limit, within seconds and under
1 GiB of memory, without a crash and without network access.

Every file is written here, byte by byte, from the format documents (formats/*/README.md);
the Rust side has the same cases in tests/hostile_{inputs,references,packages}.rs. Each
refused call runs in a child Python process (RLIMIT_AS 4 GiB as a safety net), so a crash,
a hang or a runaway allocation fails one test with a message instead of taking pytest
down; the child reports the call's time and its peak RSS.

PLY sources (`element vertex 99999999999`, 2⁶¹) are not here: only the CLI
(`icp --source`) reads PLY, the C ABI has no entry for it (tests/quick/hostile_inputs.rs covers
it through the CLI).
"""
from __future__ import annotations

import hashlib
import json
import os
import pathlib
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from dataclasses import dataclass

import numpy as np
import pytest

import cloudcontrol
from cloudcontrol import DcpPackage, fiducial_io, formats, lidar, orient_photo

REPO = pathlib.Path(__file__).resolve().parents[3]
SAMPLE_DCP = REPO / "formats" / "dcp" / "sample.dcp"
FRAME_CAMERA = REPO / "formats" / "cameras" / "frame_example.json"
FILM_CAMERA = REPO / "formats" / "cameras" / "wild_rc10.json"
CHIP = "chips/p1_1.png"

# CcpStatus (include/cloudcontrol.h).
FORMAT, INVALID_ARGUMENT, BUFFER_TOO_SMALL, NOT_ORIENTED = 5, 2, 8, 9

MAX_IMAGE_PIXELS = 1 << 30  # formats/geotiff/README.md, "Reading rasters and images"
MAX_DECODED_BYTES = 4 << 30
MAX_ORTHO_PIXELS = 1 << 32

ADDRESS_SPACE_LIMIT = 4 << 30  # safety net: the child dies instead of the machine swapping
PEAK_RSS_LIMIT_KIB = 1 << 20  # 1 GiB, the acceptance limit
CALL_SECONDS_LIMIT = 5.0  # "within seconds"
CHILD_TIMEOUT_S = 60.0  # interpreter and library start included


# ---------------------------------------------------------------------------------------
# Running one call in a child
# ---------------------------------------------------------------------------------------

_CHILD = """
import json, pathlib, resource, sys, time, importlib.util
limit = int(sys.argv[4])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
here = pathlib.Path(sys.argv[1])
sys.path.insert(0, str(here.parents[1]))  # the binding next to this test, as conftest.py
spec = importlib.util.spec_from_file_location("hostile_case", here)
mod = sys.modules[spec.name] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mod)
from cloudcontrol import CloudControlError
fn = getattr(mod, sys.argv[2])
t = time.perf_counter()
try:
    fn(*json.loads(sys.argv[3]))
    status, message = 0, ""
except CloudControlError as e:
    status, message = e.status, str(e)
took = time.perf_counter() - t
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
# ru_maxrss keeps the forking parent's peak across exec on Linux; VmHWM is this process's own.
hwm = next((int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:")), rss)
print("CASE-RESULT " + json.dumps({"status": status, "message": message, "seconds": took, "rss_kib": rss,
                                   "hwm_kib": hwm}))
"""


@dataclass
class Outcome:
    status: int
    message: str
    seconds: float
    rss_kib: int  # ru_maxrss: an upper bound (includes pytest's own peak at the fork)
    hwm_kib: int  # VmHWM: the child's own peak


def run_in_child(call: str, *args) -> Outcome:
    """Runs ``call(*args)`` (a function of this module; arguments JSON) in a fresh Python
    process under RLIMIT_AS 4 GiB and returns its status (0 when it did not raise), message,
    time in the call and peak RSS. A signal, a hang or a Python exception in the child fails
    the test with the child's stderr."""
    plain = [str(a) if isinstance(a, os.PathLike) else a for a in args]
    # faulthandler: a crash in the library prints the Python stack of the call.
    argv = [sys.executable, "-X", "faulthandler", "-c", _CHILD, __file__, call, json.dumps(plain),
            str(ADDRESS_SPACE_LIMIT)]
    try:
        p = subprocess.run(argv, capture_output=True, text=True, timeout=CHILD_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        p = None  # run() has killed the child; fail outside the handler, without its chain
    if p is None:
        pytest.fail(f"{call}{args}: no answer within {CHILD_TIMEOUT_S} s (the child was killed)")
    if p.returncode < 0:
        pytest.fail(f"{call}{args}: the child was killed by {signal.Signals(-p.returncode).name}; "
                    f"stderr:\n{p.stderr[-4000:]}")
    lines = [line for line in p.stdout.splitlines() if line.startswith("CASE-RESULT ")]
    if p.returncode != 0 or not lines:
        pytest.fail(f"{call}{args}: the child exited with {p.returncode}; stderr:\n{p.stderr[-4000:]}")
    r = Outcome(**json.loads(lines[-1][len("CASE-RESULT "):]))
    print(f"{call}: status {r.status} in {r.seconds:.3f} s, peak RSS {r.hwm_kib / 1024:.0f} MiB "
          f"(ru_maxrss {r.rss_kib / 1024:.0f} MiB): {r.message}")
    return r


def refused(call: str, *args, status: int, words) -> Outcome:
    """Runs the call in a child and asserts the clean refusal: ``status``, a message holding
    each of ``words`` (the input's name, the claim, the limit), in seconds, under 1 GiB."""
    r = run_in_child(call, *args)
    assert r.status == status, f"status {r.status}, expected {status}: {r.message}"
    for w in words:
        assert str(w) in r.message, f"message lacks {str(w)!r}: {r.message}"
    assert r.seconds < CALL_SECONDS_LIMIT, f"{call} took {r.seconds:.1f} s"
    # The child's own peak (VmHWM): ru_maxrss carries pytest's peak across fork and exec,
    # so it measured whichever test ran before (the Dask test's in-process run: 1.1 GiB).
    assert r.hwm_kib < PEAK_RSS_LIMIT_KIB, f"{call}: peak RSS {r.hwm_kib / 1024:.0f} MiB"
    return r


# ---------------------------------------------------------------------------------------
# The calls the children make (module level, so the child finds them by name)
# ---------------------------------------------------------------------------------------

def call_block_summary(path):
    formats.summary(path)


def call_convert(src, dst):
    formats.convert(src, dst)


def call_catalogue(path):
    lidar.catalogue(path, assume_crs="EPSG:32650")


def call_lidar_source_open(path):
    lidar.LidarSource(path, assume_crs="EPSG:32650")


def call_eval_checkpoints(path):
    lidar.evaluate_checkpoints(path, [[0.0, 0.0, 0.0]], assume_crs="EPSG:32650")


def call_dem_size_query(path):
    """ccp_dem_read with heights = NULL: the size query alone (BUFFER_TOO_SMALL is its
    answer for a DEM that can be read)."""
    import ctypes
    from cloudcontrol._ffi import check, lib
    w, h, gt = ctypes.c_size_t(), ctypes.c_size_t(), (ctypes.c_double * 6)()
    check(lib.ccp_dem_read(os.fsencode(path), ctypes.byref(w), ctypes.byref(h), gt, None, 0))


def call_orient_photo(camera, image, dem, scan_pixel_um=None):
    """ccp_orient_photo from the sample package, near its photos (formats/dcp/sample.dcp)."""
    orient_photo(DcpPackage(SAMPLE_DCP), camera, image, [500000.0, 4400000.0, 1000.0, 0.0, 0.0, 0.0],
                 [10.0, 1.0], dem, scan_pixel_um=scan_pixel_um)


def call_fiducial_io(camera_json, pixel_mm):
    fiducial_io(camera_json, np.zeros((64, 64), np.float32), pixel_mm=pixel_mm)


def call_orthophoto(block, dem, images_dir, out, gsd):
    formats.orthophoto(block, dem, images_dir, out, gsd=gsd)


def call_dcp_open(path):
    DcpPackage(path)


def call_dcp_import(path, store):
    DcpPackage.import_(path, store)


# ---------------------------------------------------------------------------------------
# Writers of the crafted files
# ---------------------------------------------------------------------------------------

def png(width: int, height: int, depth: int = 8, colour: int = 0, idat: bytes = b"") -> bytes:
    """A PNG (ISO 15948): signature, IHDR, one IDAT, IEND; with an empty IDAT 57 bytes
    whatever size it claims."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def las(minor: int, count: int, points: int, evlrs=()) -> bytes:
    """A LAS 1.2 (227-byte header) or 1.4 (375-byte header) file (ASPRS LAS 1.4 R15 §2.4):
    point format 0 (20-byte records), ``count`` declared, ``points`` zero records, then the
    EVLRs (length field, data) of a 1.4 file."""
    size = 375 if minor >= 4 else 227
    h = bytearray(size)
    h[0:4] = b"LASF"
    h[24:26] = bytes([1, minor])
    struct.pack_into("<HII", h, 94, size, size, 0)  # header size, offset to points, VLRs
    struct.pack_into("<BHI", h, 104, 0, 20, 0 if minor >= 4 else count)  # format, length, legacy count
    struct.pack_into("<3d", h, 131, 0.01, 0.01, 0.01)  # scale
    if minor >= 4:
        if evlrs:
            struct.pack_into("<QI", h, 235, size + 20 * points, len(evlrs))
        struct.pack_into("<Q", h, 247, count)
    h += bytes(20 * points)
    for length, data in evlrs:
        v = bytearray(60)
        v[2:7] = b"crash"
        struct.pack_into("<Q", v, 20, length)
        h += v + data
    return bytes(h)


def dem(path, crs: str = "EPSG:4547", west: float = 499_800.0, north: float = 4_400_200.0) -> pathlib.Path:
    """A 200 × 200 DEM of 2 m cells at height 0 (through ccp_dem_write)."""
    formats.write_dem(path, np.zeros((200, 200)), [west, 2.0, 0.0, north, 0.0, -2.0], crs)
    return pathlib.Path(path)


def copy_sample(dst: pathlib.Path) -> pathlib.Path:
    shutil.copytree(SAMPLE_DCP, dst)
    DcpPackage(dst)  # the copy opens: what the test changes is what it refuses
    return dst


def vrt_xml(target) -> bytes:
    """GDAL VRT reading ``target``: what a "PNG" must not be opened as."""
    return (f'<VRTDataset rasterXSize="10" rasterYSize="10"><VRTRasterBand dataType="Float32" band="1">'
            f'<SimpleSource><SourceFilename relativeToVRT="0">{target}</SourceFilename>'
            f'<SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>').encode()


def package_refused(pkg: pathlib.Path, words) -> None:
    """ccp_dcp_open and ccp_dcp_import refuse ``pkg`` naming it; the store is not made."""
    store = pkg.with_suffix(".store")
    for call, args in (("call_dcp_open", (pkg,)), ("call_dcp_import", (pkg, store))):
        refused(call, *args, status=FORMAT, words=[pkg, *words])
    assert not store.exists(), "a refused import created the store"


# ---------------------------------------------------------------------------------------
# COLMAP
# ---------------------------------------------------------------------------------------

def test_colmap_frames_bin_data_id_count(tmp_path):
    """formats/colmap/README.md, "Errors": in binary files every count (here a frame's data
    ids, 2³² − 1) times its smallest record must fit in the file's bytes. An otherwise empty
    COLMAP 4 model; ccp_block_summary and ccp_convert."""
    for f in ("cameras.bin", "images.bin", "points3D.bin", "rigs.bin"):
        (tmp_path / f).write_bytes(struct.pack("<Q", 0))
    frame = struct.pack("<QII", 1, 1, 1)  # frames, frame id, rig id
    frame += struct.pack("<7d", 1, 0, 0, 0, 0, 0, 0)  # rig_from_world: quaternion, translation
    frame += struct.pack("<IiIQ", 2**32 - 1, 0, 1, 1)  # data ids, then one (sensor, id, data id)
    frames = tmp_path / "frames.bin"
    frames.write_bytes(frame)
    words = [frames, "data id count", "4294967295", f"file of {len(frame)} bytes"]
    refused("call_block_summary", tmp_path, status=FORMAT, words=words)
    out = tmp_path.parent / "out.xml"
    refused("call_convert", tmp_path, out, status=FORMAT, words=words)
    assert not out.exists()


def test_colmap_frames_txt_data_id_count(tmp_path):
    """formats/colmap/README.md, "Errors": in text files a frame's NUM_DATA_IDS times 3
    must fit in the fields left on its line."""
    for f in ("cameras.txt", "images.txt", "points3D.txt", "rigs.txt"):
        (tmp_path / f).write_text("# empty\n")
    frames = tmp_path / "frames.txt"
    frames.write_text("# frames\n1 1 1 0 0 0 0 0 0 4294967295 CAMERA 1 1\n")
    words = [frames, "line 2", "NUM_DATA_IDS 4294967295", "holds 3 more"]
    refused("call_block_summary", tmp_path, status=FORMAT, words=words)
    refused("call_convert", tmp_path, tmp_path.parent / "out.xml", status=FORMAT, words=words)


# ---------------------------------------------------------------------------------------
# LAS / LAZ
# ---------------------------------------------------------------------------------------

LIDAR_CALLS = ("call_catalogue", "call_lidar_source_open", "call_eval_checkpoints")


def test_hand_written_las_reads(tmp_path):
    """The control: the hand-written LAS 1.4 layout, with its true count and an EVLR of its
    true length, is read (so the refusals below are of the claims, not of the layout)."""
    f = tmp_path / "good.las"
    f.write_bytes(las(4, 2, 2, [(4, bytes(4))]))
    tile = lidar.catalogue(f, assume_crs="EPSG:32650")["tiles"][0]
    assert (tile["version"], tile["point_count"], tile["point_format"]) == ("1.4", 2, 0)


def test_las_point_count_beyond_the_file(tmp_path):
    """formats/lidar/README.md, "Limits": uncompressed LAS point count × record length
    must equal the point data's bytes. A LAS 1.2 header declaring 2³² − 1 points of 20
    bytes in a 267-byte file."""
    f = tmp_path / "count.las"
    f.write_bytes(las(2, 2**32 - 1, 2))
    for call in LIDAR_CALLS:
        refused(call, f, status=FORMAT, words=[f, "declares 4294967295 points", "holds only 2"])


def test_las14_evlr_length_beyond_the_file(tmp_path):
    """formats/lidar/README.md, "Limits": each EVLR's length within the file. A LAS 1.4
    file whose one EVLR claims 2⁴⁰ bytes where 8 follow."""
    f = tmp_path / "evlr.las"
    f.write_bytes(las(4, 1, 1, [(1 << 40, bytes(8))]))
    for call in LIDAR_CALLS:
        refused(call, f, status=FORMAT, words=[f, "EVLR 0 length 1099511627776 exceeds 8"])


def test_laz_point_count_beyond_the_chunks(tmp_path):
    """formats/lidar/README.md, "Limits": the header's point count at most what the LAZ
    chunks hold. laspy (an independent LAZ writer) writes 3 points in one 50 000-point
    chunk; the legacy point count at byte 107 is then set to 2³² − 1."""
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [500_000.0, 4_400_000.0, 0.0]
    data = laspy.LasData(header)
    data.x = np.array([500_000.0, 500_001.0, 500_002.0])
    data.y = np.full(3, 4_400_000.0)
    data.z = np.full(3, 10.0)
    good = tmp_path / "good.laz"
    data.write(str(good))
    assert lidar.catalogue(good, assume_crs="EPSG:32650")["tiles"][0]["point_count"] == 3
    b = bytearray(good.read_bytes())
    struct.pack_into("<I", b, 107, 2**32 - 1)
    f = tmp_path / "count.laz"
    f.write_bytes(b)
    for call in LIDAR_CALLS:
        refused(call, f, status=FORMAT, words=[f, "point count 4294967295 exceeds 50000", "1 LAZ chunks"])


# ---------------------------------------------------------------------------------------
# Images and rasters
# ---------------------------------------------------------------------------------------

def test_png_of_100000_px_through_the_dem_size_query(tmp_path):
    """formats/geotiff/README.md, "Reading rasters and images": at most 2³⁰ pixels read
    whole, and ccp_dem_read's size query reads the header only. A 57-byte PNG claiming
    100 000 × 100 000 px; the control is a DEM that fits, whose size query answers
    BUFFER_TOO_SMALL with its size."""
    big = tmp_path / "dem.png"
    big.write_bytes(png(100_000, 100_000))
    assert big.stat().st_size == 57
    refused("call_dem_size_query", big, status=FORMAT,
            words=[big, "100000×100000", "10000000000", MAX_IMAGE_PIXELS])
    assert run_in_child("call_dem_size_query", dem(tmp_path / "dem.tif")).status == BUFFER_TOO_SMALL


@pytest.mark.parametrize("width, height, depth, colour, words", [
    (100_000, 100_000, 8, 0, ["100000×100000", "10000000000", MAX_IMAGE_PIXELS]),
    (30_000, 30_000, 16, 6, ["30000×30000", "7200000000", MAX_DECODED_BYTES]),
], ids=["grey-10^10-px", "rgba16-7.2-GB"])
def test_png_beyond_the_size_limits_as_a_photo(tmp_path, width, height, depth, colour, words):
    """formats/geotiff/README.md, "Reading rasters and images": at most 2³⁰ pixels and
    4 GiB decoded, both from the header. 57-byte PNGs as the photo of ccp_orient_photo,
    which reports an unreadable photo as NOT_ORIENTED with the reason."""
    photo = tmp_path / "photo.png"
    photo.write_bytes(png(width, height, depth, colour))
    refused("call_orient_photo", FRAME_CAMERA, photo, dem(tmp_path / "dem.tif"), status=NOT_ORIENTED,
            words=[photo, *words])


def test_png_that_is_vrt_xml(tmp_path):
    """formats/geotiff/README.md: GDAL opens only GTiff, PNG and JPEG, never VRT (a "PNG"
    holding VRT XML is refused). The VRT reads a real DEM; as a DEM (ccp_dem_read) and as
    a photo (ccp_orient_photo)."""
    target = dem(tmp_path / "secret.tif")
    fake = tmp_path / "photo.png"
    fake.write_bytes(vrt_xml(target))
    refused("call_dem_size_query", fake, status=FORMAT, words=[fake, "GTiff, PNG, JPEG"])
    refused("call_orient_photo", FRAME_CAMERA, fake, target, status=NOT_ORIENTED,
            words=[fake, "Invalid PNG signature", "GTiff, PNG, JPEG"])


# ---------------------------------------------------------------------------------------
# Parameters with physical meaning
# ---------------------------------------------------------------------------------------

def test_fiducial_mark_of_a_metre(tmp_path):
    """formats/cameras/README.md: mark dimensions are at most a tenth of the shorter film
    side (23 mm on 230 mm film). wild_rc10.json with its first mark's size_mm 1000, as a
    camera file (ccp_orient_photo: the photo is never read) and as camera_json
    (ccp_fiducial_io)."""
    cam = json.loads(FILM_CAMERA.read_text())
    cam["fiducials"][0]["shape"]["size_mm"] = 1000
    f = tmp_path / "cam.json"
    f.write_text(json.dumps(cam))
    words = ["size_mm 1000", "at most 23 mm"]
    refused("call_orient_photo", f, tmp_path / "no-such-scan.tif", dem(tmp_path / "dem.tif"), status=FORMAT,
            words=[f, *words])
    refused("call_fiducial_io", json.dumps(cam), 0.0, status=INVALID_ARGUMENT, words=["camera_json", *words])


def test_scan_pixel_of_a_picometre(tmp_path):
    """formats/cameras/README.md: scan pixel sizes given with a scan must be 3–200 µm.
    ccp_fiducial_io's pixel_mm 1e-9 and ccp_orient_photo's scan_pixel_um 1e-6."""
    refused("call_fiducial_io", FILM_CAMERA.read_text(), 1e-9, status=INVALID_ARGUMENT,
            words=["pixel_mm", "3–200 µm"])
    scan = tmp_path / "scan.png"
    scan.write_bytes(png(4, 4))
    refused("call_orient_photo", FILM_CAMERA, scan, dem(tmp_path / "dem.tif"), 1e-6, status=INVALID_ARGUMENT,
            words=["scan_pixel_um", "3–200 µm"])


def test_orthophoto_ground_pixel_far_below_the_extent(tmp_path):
    """formats/geotiff/README.md: orthophotos have at most 2³² pixels; a gsd far below
    the extent is refused naming the gsd, the extent and the limit. A COLMAP text model
    (formats/colmap/README.md) of one nadir 8 × 8 photo 400 m above a 400 m DEM: gsd 0.5 m
    gives 800 × 800 px, gsd 0.5 mm would give 6.4·10¹¹ (ccp_orthophoto)."""
    model = tmp_path / "model"
    model.mkdir()
    (model / "cameras.txt").write_text("1 PINHOLE 8 8 8 8 4 4\n")
    # Nadir: R = diag(1, −1, −1) is the quaternion (0, 1, 0, 0); t = −R·C for C = (0, 0, 400).
    (model / "images.txt").write_text("1 0 1 0 0 0 0 400 1 p1.png\n\n")
    (model / "points3D.txt").write_text("")
    (model / "cloudcontrol_georef.json").write_text(
        json.dumps({"crs": "EPSG:32650", "origin": [500_200.0, 4_400_200.0, 0.0]}))
    rows = b"".join(b"\x00" + bytes([128] * 24) for _ in range(8))  # filter byte + 8 RGB pixels
    (model / "p1.png").write_bytes(png(8, 8, 8, 2, zlib.compress(rows)))
    ground = dem(tmp_path / "dem.tif", "EPSG:32650", 500_000.0, 4_400_400.0)
    assert formats.orthophoto(model, ground, model, tmp_path / "ok.tif", gsd=0.5) == (800, 800)
    out = tmp_path / "ortho.tif"
    refused("call_orthophoto", model, ground, model, out, 0.0005, status=FORMAT,
            words=[out, "gsd 0.0005", "400.0×400.0 m", MAX_ORTHO_PIXELS])
    assert not out.exists()


# ---------------------------------------------------------------------------------------
# DCP packages
# ---------------------------------------------------------------------------------------

class Listener:
    """A listener on 127.0.0.1 counting the connections it accepts (each closed at once)."""

    def __init__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.port = self.sock.getsockname()[1]
        self.count = 0
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.count += 1
            conn.close()

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.port}/{path}"

    def accepted(self) -> int:
        time.sleep(0.1)  # a connection in flight
        return self.count


def manifest(crs: str) -> dict:
    """A DCP manifest (formats/dcp/README.md) without photos, points or files."""
    return {"format": "cloudcontrol-dcp", "version": 1, "crs": crs, "epoch": {"name": "2019"},
            "source": "hand-written", "gsd_m": 0.1, "accuracy": {"plan_m": 0.05, "height_m": 0.08},
            "photos": [], "points": [], "files": {}}


def test_dcp_manifest_crs_that_names_a_url_or_a_file(tmp_path):
    """formats/README.md, "CRS definitions": a definition is never fetched or read from a
    file; formats/dcp/README.md: `crs` is never a URL or a file name. A listener on
    127.0.0.1 sees no connection (its own control: a direct connection is counted), and
    the manifest with "EPSG:4547" instead opens."""
    listener = Listener()
    prj = tmp_path / "puwg92.prj"
    prj.write_text('PROJCS["ETRF2000-PL / CS92",GEOGCS["ETRF2000-PL",DATUM["ETRF2000_Poland",'
                   'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],'
                   'UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
                   'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",19],'
                   'PARAMETER["scale_factor",0.9993],PARAMETER["false_easting",500000],'
                   'PARAMETER["false_northing",-5300000],UNIT["metre",1]]')
    cases = [
        (listener.url("crs.wkt"), "URL"),
        (f"/vsicurl/{listener.url('crs.wkt')}", "URL"),
        (str(prj), "file name"),
        (f"@{prj}", "file name"),
        (f"+proj=utm +zone=33 +ellps=GRS80 +units=m +nadgrids=@{listener.url('grid.tif')}", "+nadgrids"),
    ]
    for k, (crs, what) in enumerate(cases):
        pkg = tmp_path / f"crs{k}.dcp"
        pkg.mkdir()
        (pkg / "manifest.json").write_text(json.dumps(manifest(crs)))
        if k == 0:
            package_refused(pkg, ["manifest.json: crs", what])
        else:
            refused("call_dcp_open", pkg, status=FORMAT, words=[pkg, "manifest.json: crs", what])
    assert listener.accepted() == 0, "a DCP manifest made the library connect"
    socket.create_connection(("127.0.0.1", listener.port)).close()
    assert listener.accepted() == 1, "the listener does not see connections"
    good = tmp_path / "good.dcp"
    good.mkdir()
    (good / "manifest.json").write_text(json.dumps(manifest("EPSG:4547")))
    assert len(DcpPackage(good)) == 0


def test_dcp_png_chip_that_is_vrt_xml(tmp_path):
    """formats/dcp/README.md: chips are PNG, read with a PNG decoder (never GDAL), each
    chip's size read from its header. A chip replaced by VRT XML and listed with its own
    SHA-256, so only the content tells."""
    pkg = copy_sample(tmp_path / "vrt.dcp")
    body = vrt_xml("/etc/passwd")
    (pkg / CHIP).write_bytes(body)
    m = json.loads((pkg / "manifest.json").read_text())
    m["files"][CHIP] = hashlib.sha256(body).hexdigest()
    (pkg / "manifest.json").write_text(json.dumps(m))
    package_refused(pkg, [CHIP, "cannot read the image header"])


def test_dcp_chip_that_is_a_symbolic_link(tmp_path):
    """formats/dcp/README.md, "Validation on import": every chip is a regular file inside
    the package; a symbolic link (even to identical bytes) is refused without being
    opened. A link out of the package to the chip's own bytes, and one to /dev/zero."""
    pkg = copy_sample(tmp_path / "outside.dcp")
    elsewhere = tmp_path / "elsewhere.png"
    (pkg / CHIP).rename(elsewhere)
    (pkg / CHIP).symlink_to(elsewhere)
    package_refused(pkg, [CHIP, "symbolic link", "elsewhere.png"])
    pkg = copy_sample(tmp_path / "zero.dcp")
    (pkg / CHIP).unlink()
    (pkg / CHIP).symlink_to("/dev/zero")
    package_refused(pkg, [CHIP, "symbolic link", "/dev/zero"])


def test_dcp_chip_that_is_a_fifo(tmp_path):
    """formats/dcp/README.md, "Validation on import": a FIFO is refused without being
    opened (opening it for reading would wait for a writer: the child's timeout catches a
    hang)."""
    pkg = copy_sample(tmp_path / "fifo.dcp")
    (pkg / CHIP).unlink()
    os.mkfifo(pkg / CHIP)
    package_refused(pkg, [CHIP, "is a FIFO"])


def test_the_binding_under_test_is_this_one():
    """The children import the binding next to this file, as conftest.py does here."""
    assert pathlib.Path(cloudcontrol.__file__).resolve().parents[1] == pathlib.Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------
# Panics, silent acceptance and partial runs (issue 51 item 8, issue 52 item 3)
# ---------------------------------------------------------------------------------------

PARTIAL = 12  # CCP_STATUS_PARTIAL


def msgpack(v) -> bytes:
    """MessagePack (msgpack.org spec) of None, bools, ints, floats, strings, lists and
    dicts: what rmp-serde reads as the task files' structs (field names kept)."""
    if v is None:
        return b"\xc0"
    if isinstance(v, bool):
        return b"\xc3" if v else b"\xc2"
    if isinstance(v, int):
        return struct.pack(">Bq", 0xd3, v) if v < 0 else struct.pack(">BQ", 0xcf, v)
    if isinstance(v, float):
        return struct.pack(">Bd", 0xcb, v)
    if isinstance(v, str):
        b = v.encode()
        return struct.pack(">BI", 0xdb, len(b)) + b
    if isinstance(v, (list, tuple)):
        return struct.pack(">BI", 0xdd, len(v)) + b"".join(msgpack(x) for x in v)
    if isinstance(v, dict):
        return struct.pack(">BI", 0xdf, len(v)) + b"".join(msgpack(k) + msgpack(x) for k, x in v.items())
    raise TypeError(type(v))


def las_points(scale=(0.01, 0.01, 0.01), offset=(500000.0, 4400000.0, 0.0), n: int = 100) -> bytes:
    """A LAS 1.2 file (227-byte header, format 0) of ``n`` ground points of strip 1 on a
    1 m grid, with the given scale factors and offsets (header bytes 131 and 155)."""
    h = bytearray(227)
    h[0:4] = b"LASF"
    h[24:26] = bytes([1, 2])
    struct.pack_into("<HII", h, 94, 227, 227, 0)
    struct.pack_into("<BHII", h, 104, 0, 20, n, n)
    struct.pack_into("<3d", h, 131, *scale)
    struct.pack_into("<3d", h, 155, *offset)
    struct.pack_into("<6d", h, 179, 500009.0, 500000.0, 4400009.0, 4400000.0, 120.0, 120.0)
    for i in range(n):
        h += struct.pack("<iiiHBBbBH", 100 * (i % 10), 100 * (i // 10), 12000, 100, 9, 2, 0, 0, 1)
    return bytes(h)


def sources_task(root: pathlib.Path, offset_m) -> tuple[pathlib.Path, dict]:
    """A `sources` stage's task folder (formats/workflow/README.md, "Tasks") for one tile:
    plan.json, screen-00000.msgpack, strip_offsets.msgpack giving strip 1 ``offset_m``;
    returns it and the tile's `clean` task."""
    tile = root / "t.las"
    root.mkdir(parents=True)
    tile.write_bytes(las_points())
    folder = root / "run" / "tasks" / "sources" / "0123456789abcdef"
    folder.mkdir(parents=True)
    (folder / "plan.json").write_text(json.dumps({"stride": 1, "tiles": [{
        "file": str(tile), "version": "1.2", "point_format": 0, "compressed": False,
        "point_count": 100, "bounds": [500000.0, 4400000.0, 120.0, 500009.0, 4400009.0, 120.0],
        "area_m2": 81.0, "density_pts_m2": 1.23, "classes": {"2": 100}, "point_sources": {"1": 100},
        "gps_time_range": None, "gps_time_type": "week", "acquisition_dates": None,
        "creation_date": None, "crs": "EPSG:4547", "crs_source": "assumed", "vertical_crs": None}]}))
    (folder / "screen-00000.msgpack").write_bytes(msgpack({"tile": "t.las", "screen": {
        "noise": [], "outliers": None, "sample_xyz": [], "sample_src": []}}))
    (folder / "strip_offsets.msgpack").write_bytes(msgpack({
        "model": "vertical", "reference": None, "sigma0_m": 0.02, "pairs": [],
        "strips": [{"source_id": 1, "points": 100, "offset_m": list(offset_m), "sigma_m": [0.01] * 3}]}))
    return folder, {"kind": "clean", "stage": "sources", "folder": str(folder), "index": 0, "item": "t.las"}


def call_task_run(task):
    cloudcontrol.pipeline.run_task(task)


def call_camera(width, height, fx):
    cloudcontrol.Camera(width, height, fx, fx, width / 2, height / 2)


def call_project_run(project):
    cloudcontrol.run(project)


def call_project_run_partial_ok(project):
    """The summary of a partial run is returned when asked for: it names the epoch."""
    res = cloudcontrol.run(project, partial_ok=True)
    p = res["partial"]
    assert [(e["epoch"], e["oriented"], e["total"]) for e in p] == [("digital_2012", 0, 2)], p


def test_task_file_with_nan_strip_offsets(tmp_path):
    """formats/workflow/README.md, "Tasks": every value read from a task file is checked
    where it is decoded. NaN (and absurd) strip offsets used to panic (status PANIC) and
    leave a `.part.las`; now FORMAT naming the file and the field, nothing written."""
    folder, task = sources_task(tmp_path / "sane", [0.0, 0.0, 0.05])
    assert run_in_child("call_task_run", task).status == 0
    assert (folder / "lidar" / "t.las").is_file()
    for name, offset, words in [
        ("nan", [0.0, 0.0, float("nan")], ["strip 1 offset_m[2] = NaN is not finite"]),
        ("far", [0.0, 1e6, 0.0], ["strip 1 offset_m 1000000 is beyond 100 m"]),
    ]:
        folder, task = sources_task(tmp_path / name, offset)
        refused("call_task_run", task, status=FORMAT,
                words=[folder / "strip_offsets.msgpack", "task file", *words])
        assert not (folder / "lidar" / "t.las").exists()
        assert [p for p in tmp_path.rglob("*") if ".part" in p.name] == []


@pytest.mark.parametrize("scale,offset,words", [
    ((float("nan"), 0.01, 0.01), (500000.0, 4400000.0, 0.0), "x scale factor NaN"),
    ((0.01, 0.0, 0.01), (500000.0, 4400000.0, 0.0), "y scale factor 0"),
    ((0.01, 0.01, 0.01), (500000.0, float("nan"), 0.0), "y offset NaN"),
])
def test_las_header_with_a_nan_or_zero_scale_or_offset(tmp_path, scale, offset, words):
    """formats/lidar/README.md, "Limits": a NaN or 0 scale or a NaN offset is refused when
    the file is opened, naming the field (the tile used to be read with every point at NaN
    and then dropped from a run)."""
    f = tmp_path / "t.las"
    f.write_bytes(las_points(scale, offset))
    for call in LIDAR_CALLS:
        refused(call, f, status=FORMAT, words=[f, words])


def test_implausible_cameras(tmp_path):
    """formats/cameras/README.md: a camera outside the plausible ranges is refused when it
    is made (ccp_camera_new_frame), naming the field."""
    refused("call_camera", 4000, 3000, 1e-300, status=INVALID_ARGUMENT,
            words=["fx = 1e-300 px is not a focal length", "200 to 4e12 px"])
    refused("call_camera", 300000, 200000, 3000.0, status=INVALID_ARGUMENT,
            words=["image size 300000×200000", "at most 200000 px"])


def digital_project(blk: pathlib.Path, camera: str) -> pathlib.Path:
    """The tiny block's digital epoch controlled by its orthophoto and DEM (a second's run)."""
    p = blk / "project_digital.toml"
    p.write_text(f"""name = "hostile-status"
crs = "EPSG:4547"
output = "run"
[control]
orthophoto = "orthophoto/orthophoto.tif"
dem = "orthophoto/dem.tif"
dem_sigma_m = 0.1
[[archive]]
name = "digital_2012"
date = "2012-08-14"
photos = "epochs/digital_2012/images"
camera = "{camera}"
pos = "epochs/digital_2012/pos.csv"
[thresholds]
control_interval_px = 60
chip_size_px = 193
""")
    return p


def test_a_run_whose_epoch_orients_nothing_is_partial(tmp_path, shared_block):
    """formats/project/README.md, "Exit statuses": a camera of 1500 × 1000 for 400 × 266
    photos is refused before any work (INVALID_ARGUMENT, naming the camera file and both
    sizes); photos whose headers read but whose data is cut short orient none of them:
    ccp_project_run returns PARTIAL (12) with the epoch, the count and the reason, and
    Python raises PartialRunError carrying the summary (or returns it with partial_ok)."""
    blk = shared_block("tiny", 2, "good", tmp_path / "block")
    (blk / "camera_1500.json").write_text(json.dumps(
        {"kind": "frame", "width": 1500, "height": 1000, "fx": 1800.0, "fy": 1800.0, "cx": 750.0, "cy": 500.0}))
    r = refused("call_project_run", digital_project(blk, "camera_1500.json"),
                status=INVALID_ARGUMENT,
                words=["camera_1500.json", "the camera is 1500×1000 px", "is 400×266 px"])
    assert not (blk / "run" / "sources").exists(), "a stage ran"
    for png in sorted((blk / "epochs/digital_2012/images").glob("*.png")):
        data = png.read_bytes()
        png.write_bytes(data[:len(data) // 2])
    project = digital_project(blk, "epochs/digital_2012/camera.json")
    r = refused("call_project_run", project, status=PARTIAL,
                words=["partial run", "epoch digital_2012: 0 of 2 photos oriented", "image "])
    assert r.message.startswith("[PARTIAL]")
    assert run_in_child("call_project_run_partial_ok", project).status == 0
    try:
        cloudcontrol.run(project)
    except cloudcontrol.PartialRunError as e:
        assert e.status == PARTIAL and e.partial[0]["epoch"] == "digital_2012"
        assert "colmap" not in json.dumps(e.summary["products"].get("digital_2012", []))
    else:
        pytest.fail("a partial run did not raise")
