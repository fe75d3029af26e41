//! Unit tests of `formats::crs_input`.

mod tests {
    use cloudcontrol::formats::crs_input::*;
    use cloudcontrol::formats::FormatError;

    #[test]
    fn accepted_forms() {
        assert_eq!(classify("EPSG:2180").unwrap(), CrsSyntax::Epsg);
        assert_eq!(classify("epsg:32650+5773").unwrap(), CrsSyntax::Epsg);
        assert_eq!(
            classify("+proj=utm +zone=33 +datum=WGS84 +units=m +no_defs").unwrap(),
            CrsSyntax::ProjString
        );
        let merc = "PROJCS[\"WGS 84 / Pseudo-Mercator\",GEOGCS[\"WGS 84\"],\
                    EXTENSION[\"PROJ4\",\"+proj=merc +a=6378137 +nadgrids=@null +wktext\"]]";
        assert_eq!(classify(merc).unwrap(), CrsSyntax::Wkt);
        let uri =
            "PROJCRS[\"x\",ID[\"EPSG\",2180,URI[\"http://www.opengis.net/def/crs/EPSG/0/2180\"]]]";
        assert_eq!(classify(uri).unwrap(), CrsSyntax::Wkt);
        // Grids by bare name, as GDAL 2 wrote them: PROJ looks in its own folders.
        for ok in [
            "+proj=longlat +ellps=WGS84 +geoidgrids=egm96_15.gtx,@us_nga_egm08_25.tif",
            "VERT_CS[\"EGM96\",VERT_DATUM[\"EGM96\",2005,EXTENSION[\"PROJ4_GRIDS\",\"egm96_15.gtx\"]]]",
            "BOUNDCRS[SOURCECRS[],ABRIDGEDTRANSFORMATION[PARAMETERFILE[\"f\",\"ntv2_0.gsb\"]]]",
            r#"{"type":"BoundCRS","transformation":{"parameters":[{"name":"f","value":"ntv2_0.gsb"}]}}"#,
        ] {
            assert!(classify(ok).is_ok(), "{ok}: {:?}", classify(ok));
        }
        assert_eq!(
            classify(
                r#"{"$schema":"https://proj.org/x.json","type":"ProjectedCRS","name":"a / b"}"#
            )
            .unwrap(),
            CrsSyntax::ProjJson
        );
    }

    #[test]
    fn references_refused() {
        for bad in [
            "http://127.0.0.1:1/crs",
            "https://example.org/2180.prj",
            "/vsicurl/http://127.0.0.1:1/x",
            "/etc/passwd",
            "./local.prj",
            "@list.txt",
            "DICT:/etc/passwd,1",
            "file:///etc/passwd",
            "ESRI::/tmp/x.prj",
            "+proj=longlat +init=/tmp/epsg:4326",
            "+init=epsg:4326",
            "+proj=utm +zone=33 +nadgrids=@http://127.0.0.1:1/g.tif",
            "+proj=utm +zone=33 +geoidgrids=../egm96_15.gtx",
            "+proj=utm +zone=33 +geoidgrids=.egm96_15.gtx",
            "+proj=utm +zone=33 +nadgrids=a.gsb,/etc/passwd",
            "PROJCS[\"x\",EXTENSION[\"PROJ4\",\"+proj=merc +nadgrids=/tmp/g.gsb\"]]",
            "VERT_CS[\"x\",EXTENSION[\"PROJ4_GRIDS\",\"/tmp/g.gtx\"]]",
            "BOUNDCRS[SOURCECRS[],PARAMETERFILE[\"f\",\"/tmp/g.gsb\"]]",
            "PROJCS[\"http://127.0.0.1:1/x\"]",
            r#"{"type":"BoundCRS","transformation":{"parameters":[{"name":"f","value":"/tmp/g.gsb"}]}}"#,
            r#"{"type":"ProjectedCRS","name":"http://127.0.0.1:1/"}"#,
            r#"{"type":"Foo"}"#,
        ] {
            match classify(bad) {
                Err(FormatError::Crs { crs, .. }) => assert_eq!(crs, excerpt(bad)),
                other => panic!("{bad}: {other:?}"),
            }
        }
    }
}
