//! Unit tests of `formats::tiff_window`: windows of uncompressed TIFFs in the layouts a
//! scanner or GDAL writes (strips and tiles, 8 and 16 bits, grey and RGB(A), little- and
//! big-endian) have the grey values the whole decode gives; other TIFFs are
//! left to other readers, and a truncated one is refused naming the file.

mod tests {
    use cloudcontrol::formats::gdal::Driver;
    use cloudcontrol::formats::image_open::decode_grey;
    use cloudcontrol::formats::tiff_window::TiffWindows;
    use std::path::Path;

    const W: usize = 61;
    const H: usize = 45;

    /// A sample of band `b` at (x, y) spanning the type's range (`max`).
    fn value(x: usize, y: usize, b: usize, max: u32) -> u32 {
        ((x * 7919 + y * 104_729 + b * 1_299_709) as u32).wrapping_mul(2_654_435_761) % (max + 1)
    }

    /// A `W`×`H` TIFF of `bands` bands written by GDAL with creation `options`.
    fn write<T: cloudcontrol::formats::gdal::GdalType>(
        path: &Path,
        bands: usize,
        options: &[&str],
        of: impl Fn(u32) -> T,
        max: u32,
    ) {
        let driver = Driver::by_name("GTiff").unwrap();
        let mut ds = driver.create::<T>(path, (W, H), bands, options).unwrap();
        for b in 1..=bands {
            let data: Vec<T> = (0..W * H)
                .map(|i| of(value(i % W, i / W, b, max)))
                .collect();
            let mut band = ds.rasterband(b).unwrap();
            band.write((0, 0), (W, H), &data).unwrap();
            if options.contains(&"ALPHA=YES") && b == bands {
                band.set_alpha().unwrap();
            }
        }
        ds.flush_cache().unwrap();
    }

    /// Every window of a few shapes and places (edges and chunk boundaries included) has
    /// the values of the whole decode.
    fn windows_agree(path: &Path) {
        let (w, h, whole) = decode_grey(path).unwrap();
        assert_eq!((w, h), (W, H));
        let mut t = TiffWindows::open(path)
            .unwrap()
            .unwrap_or_else(|| panic!("{} is read by windows", path.display()));
        assert_eq!(t.size(), (W, H));
        for (c, r, ww, wh) in [
            (0, 0, W, H),
            (0, 0, 1, 1),
            (W - 1, H - 1, 1, 1),
            (3, 5, 17, 11),
            (30, 14, 31, 31),
            (13, 0, 40, 2),
        ] {
            let mut got = Vec::new();
            t.read((c, r, ww, wh), &mut got).unwrap();
            for j in 0..wh {
                for i in 0..ww {
                    assert_eq!(
                        got[j * ww + i].to_bits(),
                        whole[(r + j) * W + c + i].to_bits(),
                        "{} ({}, {})",
                        path.display(),
                        c + i,
                        r + j
                    );
                }
            }
        }
        assert!(t.read((W - 3, 0, 4, 1), &mut Vec::new()).is_err());
    }

    #[test]
    fn windows_have_the_values_of_the_whole_image() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let u8_of = |v: u32| v as u8;
        let u16_of = |v: u32| v as u16;
        let p = d.join("grey8_strips.tif");
        write(&p, 1, &["BLOCKYSIZE=4"], u8_of, 255);
        windows_agree(&p);
        let p = d.join("grey16_tiles_big_endian.tif");
        let tiles = [
            "TILED=YES",
            "BLOCKXSIZE=16",
            "BLOCKYSIZE=32",
            "ENDIANNESS=BIG",
        ];
        write(&p, 1, &tiles, u16_of, 65535);
        windows_agree(&p);
        let p = d.join("rgb8_tiles.tif");
        let tiles = [
            "PHOTOMETRIC=RGB",
            "TILED=YES",
            "BLOCKXSIZE=32",
            "BLOCKYSIZE=16",
        ];
        write(&p, 3, &tiles, u8_of, 255);
        windows_agree(&p);
        let p = d.join("rgba16_strips.tif");
        let strips = ["PHOTOMETRIC=RGB", "ALPHA=YES", "BLOCKYSIZE=7"];
        write(&p, 4, &strips, u16_of, 65535);
        windows_agree(&p);
        // What the image crate writes (the scans of the tests).
        let img = image::GrayImage::from_fn(W as u32, H as u32, |x, y| {
            image::Luma([value(x as usize, y as usize, 1, 255) as u8])
        });
        let p = d.join("image_crate.tif");
        img.save(&p).unwrap();
        windows_agree(&p);
    }

    #[test]
    fn compressed_and_truncated_tiffs() {
        let dir = tempfile::tempdir().unwrap();
        // Compressed: not read here (GDAL reads it by windows).
        let lzw = dir.path().join("lzw.tif");
        write(&lzw, 1, &["COMPRESS=LZW"], |v| v as u8, 255);
        assert!(TiffWindows::open(&lzw).unwrap().is_none());
        // Not a TIFF at all.
        let png = dir.path().join("grey.png");
        image::GrayImage::new(4, 4).save(&png).unwrap();
        assert!(TiffWindows::open(&png).unwrap().is_none());
        // Cut short: refused whole, naming the file, also when compressed.
        for (name, options) in [
            ("cut.tif", vec!["BLOCKYSIZE=4"]),
            ("cut_lzw.tif", vec!["COMPRESS=LZW", "BLOCKYSIZE=4"]),
        ] {
            let p = dir.path().join(name);
            write(&p, 1, &options, |v| v as u8, 255);
            let bytes = std::fs::read(&p).unwrap();
            // GDAL writes the IFD first and the strips after it.
            std::fs::write(&p, &bytes[..bytes.len() - 100]).unwrap();
            let e = TiffWindows::open(&p).unwrap_err().to_string();
            assert!(
                e.contains(name) && e.contains("truncated or corrupt TIFF"),
                "{e}"
            );
        }
    }
}
