//! PCD and PLY clouds against independent readers and writers: every real PCD of
//! `../shared/data/pcd` decodes to the points `pypcd4` reads, and four of them written again by
//! `pypcd4` (binary_compressed) and `plyfile` (ascii, binary little- and big-endian, with extra
//! properties and a face element) decode bit for bit to them; `inspect` names the format.

use crate::util::*;

/// The reference points of a cloud as float32 `x y z 0` records (a KITTI `.bin`, read by
/// toporec's own reader), written by Python beside the clouds it writes.
const WRITE: &str = r#"
import sys, numpy as np
from pypcd4 import PointCloud, Encoding
from plyfile import PlyData, PlyElement
src, out, variants = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
pc = PointCloud.from_path(src)
xyz = pc.numpy(("x", "y", "z")).astype(np.float32)
xyz = xyz[np.isfinite(xyz).all(axis=1)]
ref = np.zeros((len(xyz), 4), np.float32); ref[:, :3] = xyz
ref.tofile(out + "/reference.bin")
if not variants:
    sys.exit(0)
pc.save(out + "/compressed.pcd", encoding=Encoding.BINARY_COMPRESSED)
v = np.zeros(len(xyz), dtype=[("red", "u1"), ("x", "f4"), ("y", "f4"), ("z", "f4"), ("t", "f8")])
v["x"], v["y"], v["z"], v["red"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], 7
f = np.zeros(1, dtype=[("vertex_indices", "O")]); f["vertex_indices"][0] = np.array([0, 1, 2], np.int32)
elements = [PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")]
PlyData(elements, text=True).write(out + "/ascii.ply")
PlyData(elements, byte_order="<").write(out + "/little.ply")
PlyData(elements, byte_order=">").write(out + "/big.ply")
"#;

/// The clouds written again by the independent writers (the rest are only read): the two tiny
/// ones, the ten-field VLP-16 frame and a Hesai frame; the suite stays fast.
fn variants(cloud: &std::path::Path) -> bool {
    let name = cloud.file_name().unwrap().to_str().unwrap();
    ["ascii_xyz.pcd", "binary_xyz_pcl.pcd", "velodyne_vlp16.pcd", "hesai_at128.pcd"].contains(&name)
}

#[test]
fn pcd_and_ply_equal_independent_readers_and_writers() {
    let Some(data) = shared_data("pcd_and_ply_equal_independent_readers_and_writers") else { return };
    if !python_with("pcd_and_ply_equal_independent_readers_and_writers", &["pypcd4", "plyfile", "numpy"]) {
        return;
    }
    let dir = scratch_dir("clouds");
    let mut clouds: Vec<_> = ["pcd/nebula", "pcd/kitti_raw_city"]
        .iter()
        .flat_map(|d| std::fs::read_dir(data.join(d)).unwrap().flatten().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "pcd"))
        .collect();
    clouds.sort();
    assert_eq!(clouds.len(), 16);
    for (i, cloud) in clouds.iter().enumerate() {
        let out = dir.join(i.to_string());
        std::fs::create_dir_all(&out).unwrap();
        let o = std::process::Command::new("python3")
            .args([
                "-c",
                WRITE,
                cloud.to_str().unwrap(),
                out.to_str().unwrap(),
                if variants(cloud) { "1" } else { "0" },
            ])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}: {}", cloud.display(), text(&o.stderr));
        let reference = read_cloud(&out.join("reference.bin"));
        assert!(!reference.is_empty(), "{}", cloud.display());
        let written = ["compressed.pcd", "ascii.ply", "little.ply", "big.ply"].map(|f| out.join(f));
        let reads = if variants(cloud) {
            [std::slice::from_ref(cloud), &written].concat()
        } else {
            vec![cloud.clone()]
        };
        for read in reads {
            let points = read_cloud(&read);
            assert!(
                points == reference,
                "{} ({}): {} points, {} expected",
                cloud.display(),
                read.display(),
                points.len(),
                reference.len()
            );
        }
    }
    // inspect names the format and the points.
    let o = toporec(&["inspect", data.join("pcd/nebula/hesai_64.pcd").to_str().unwrap()]);
    assert!(
        o.status.success() && text(&o.stdout).contains("pcd cloud") && text(&o.stdout).contains("93591"),
        "{}",
        text(&o.stdout)
    );
    let o = toporec(&[
        "inspect",
        dir.join(format!("{}/big.ply", clouds.iter().position(|c| variants(c)).unwrap())).to_str().unwrap(),
    ]);
    assert!(o.status.success() && text(&o.stdout).contains("ply cloud"), "{}", text(&o.stdout));
}
