//! g2o's text format of a pose graph, read and written: `VERTEX_SE2 id x y θ`, `EDGE_SE2 i j dx
//! dy dθ` and the 6 upper-triangular entries of its information matrix, `VERTEX_SE3:QUAT id x y
//! z qx qy qz qw`, `EDGE_SE3:QUAT i j x y z qx qy qz qw` and its 21, `FIX id…`; `#` starts a
//! comment. An SE(3) edge's information is in g2o's order (translation, then rotation), applied to
//! the error's translation and rotation-vector parts as GTSAM's `readG2o` applies it.
//!
//! Written back, a graph keeps every line as it was read but the vertices', which take the
//! optimized poses. An edge between vertices whose ids are not consecutive is a loop: the robust
//! cost may reject it ([`super::solve`]).

use super::lie::{Pose, Se2, Se3};
use super::solve::{Edge, Graph};
use crate::error::{Error, Result, ResultExt};
use nalgebra::{Isometry2, Isometry3, Quaternion, SMatrix, Translation3, UnitQuaternion, Vector2};
use std::collections::HashMap;
use std::io::Write;
use std::path::Path;

/// A g2o graph: planar or spatial, with the lines it was read from.
pub enum G2o {
    /// `VERTEX_SE2` / `EDGE_SE2`.
    Plane(Read<Se2, 3>),
    /// `VERTEX_SE3:QUAT` / `EDGE_SE3:QUAT`.
    Space(Read<Se3, 6>),
}

/// A graph as read: the graph, each vertex's id, and the file's lines (each vertex's line by
/// index, to be written back with its pose).
pub struct Read<P, const D: usize> {
    /// The graph (vertices by their order in the file).
    pub graph: Graph<P, D>,
    /// Each vertex's g2o id.
    pub ids: Vec<i64>,
    /// The file's lines.
    lines: Vec<String>,
    /// The line of each vertex.
    vertex_line: Vec<usize>,
}

/// The numbers of a line after its tag, exactly `n` of them.
fn numbers(path: &Path, line: usize, words: &[&str], n: usize) -> Result<Vec<f64>> {
    let bad =
        || Error::invalid(format!("{}:{line}: expected {n} numbers after `{}`", path.display(), words[0]));
    if words.len() != n + 1 {
        return Err(bad());
    }
    let v: Option<Vec<f64>> =
        words[1..].iter().map(|w| w.parse::<f64>().ok().filter(|x| x.is_finite())).collect();
    v.ok_or_else(bad)
}

/// The symmetric matrix of `D`'s upper-triangular entries, row by row.
fn upper<const D: usize>(v: &[f64]) -> SMatrix<f64, D, D> {
    let mut m = SMatrix::<f64, D, D>::zeros();
    let mut k = 0;
    for i in 0..D {
        for j in i..D {
            m[(i, j)] = v[k];
            m[(j, i)] = v[k];
            k += 1;
        }
    }
    m
}

/// A unit quaternion from g2o's `qx qy qz qw` (normalized).
fn quaternion(q: &[f64]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]))
}

/// Reads a g2o file (see the module doc). A malformed or unknown line is an error naming its
/// number; so are a graph mixing SE(2) and SE(3), an edge to a vertex the file does not have,
/// and a file with no vertex.
pub fn read(path: &Path) -> Result<G2o> {
    let text = std::fs::read_to_string(path).at(path)?;
    let lines: Vec<String> = text.lines().map(str::to_string).collect();
    let kind = lines.iter().find_map(|l| match l.split_whitespace().next() {
        Some("VERTEX_SE2" | "EDGE_SE2") => Some(2),
        Some("VERTEX_SE3:QUAT" | "EDGE_SE3:QUAT") => Some(3),
        _ => None,
    });
    match kind {
        Some(2) => parse::<Se2, 3>(path, lines, "VERTEX_SE2", "EDGE_SE2").map(G2o::Plane),
        Some(_) => parse::<Se3, 6>(path, lines, "VERTEX_SE3:QUAT", "EDGE_SE3:QUAT").map(G2o::Space),
        None => Err(Error::invalid(format!(
            "{}: no VERTEX_SE2 or VERTEX_SE3:QUAT line: not a g2o pose graph",
            path.display()
        ))),
    }
}

/// A pose as g2o writes it on a vertex line (and an edge line before its information).
pub trait FromG2o: Sized {
    /// Numbers on a vertex line, and on an edge line before its information.
    const VALUES: usize;
    /// The pose of those numbers.
    fn from_values(v: &[f64]) -> Self;
    /// Its numbers.
    fn to_values(&self) -> Vec<f64>;
}

impl FromG2o for Se2 {
    const VALUES: usize = 3;
    fn from_values(v: &[f64]) -> Self {
        Se2(Isometry2::new(Vector2::new(v[0], v[1]), v[2]))
    }
    fn to_values(&self) -> Vec<f64> {
        vec![self.0.translation.x, self.0.translation.y, self.0.rotation.angle()]
    }
}

impl FromG2o for Se3 {
    const VALUES: usize = 7;
    fn from_values(v: &[f64]) -> Self {
        Se3(Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), quaternion(&v[3..7])))
    }
    fn to_values(&self) -> Vec<f64> {
        let t = self.0.translation.vector;
        let q = self.0.rotation.quaternion();
        vec![t.x, t.y, t.z, q.i, q.j, q.k, q.w]
    }
}

fn parse<P: Pose<D> + FromG2o, const D: usize>(
    path: &Path,
    lines: Vec<String>,
    vertex_tag: &str,
    edge_tag: &str,
) -> Result<Read<P, D>> {
    let info_values = D * (D + 1) / 2;
    let mut poses = Vec::new();
    let mut ids = Vec::new();
    let mut vertex_line = Vec::new();
    let mut index: HashMap<i64, usize> = HashMap::new();
    let mut edges = Vec::new();
    let mut fix = Vec::new();
    let id_of = |w: &str, line: usize| -> Result<i64> {
        w.parse::<i64>()
            .map_err(|_| Error::invalid(format!("{}:{line}: `{w}` is not a vertex id", path.display())))
    };
    for (i, l) in lines.iter().enumerate() {
        let line = i + 1;
        let body = l.split('#').next().unwrap_or_default();
        let words: Vec<&str> = body.split_whitespace().collect();
        let Some(&tag) = words.first() else { continue };
        if tag == vertex_tag {
            if words.len() < 2 {
                return Err(Error::invalid(format!("{}:{line}: a vertex with no id", path.display())));
            }
            let id = id_of(words[1], line)?;
            let v = numbers(path, line, &[&[tag][..], &words[2..]].concat(), P::VALUES)?;
            if index.insert(id, poses.len()).is_some() {
                return Err(Error::invalid(format!("{}:{line}: vertex {id} given twice", path.display())));
            }
            poses.push(P::from_values(&v));
            ids.push(id);
            vertex_line.push(i);
        } else if tag == edge_tag {
            if words.len() < 3 {
                return Err(Error::invalid(format!("{}:{line}: an edge with no vertices", path.display())));
            }
            let (a, b) = (id_of(words[1], line)?, id_of(words[2], line)?);
            let v = numbers(path, line, &[&[tag][..], &words[3..]].concat(), P::VALUES + info_values)?;
            let information = upper::<D>(&v[P::VALUES..]);
            edges.push((line, a, b, P::from_values(&v), information));
        } else if tag == "FIX" {
            for w in &words[1..] {
                fix.push((line, id_of(w, line)?));
            }
        } else if matches!(tag, "VERTEX_SE2" | "EDGE_SE2" | "VERTEX_SE3:QUAT" | "EDGE_SE3:QUAT") {
            return Err(Error::invalid(format!(
                "{}:{line}: `{tag}` in a graph of {vertex_tag}: SE(2) and SE(3) lines mixed",
                path.display()
            )));
        } else {
            return Err(Error::invalid(format!(
                "{}:{line}: unknown line `{tag}` (toporec reads VERTEX_SE2, EDGE_SE2, VERTEX_SE3:QUAT, EDGE_SE3:QUAT, FIX)",
                path.display()
            )));
        }
    }
    let vertex = |line: usize, id: i64| -> Result<usize> {
        index
            .get(&id)
            .copied()
            .ok_or_else(|| Error::invalid(format!("{}:{line}: no vertex {id} in the file", path.display())))
    };
    let mut graph_edges = Vec::new();
    for (line, a, b, measured, information) in edges {
        let (from, to) = (vertex(line, a)?, vertex(line, b)?);
        graph_edges.push(Edge { from, to, measured, information, robust: (a - b).abs() != 1 });
    }
    let mut fixed = vec![false; poses.len()];
    for (line, id) in fix {
        fixed[vertex(line, id)?] = true;
    }
    if poses.is_empty() {
        return Err(Error::invalid(format!("{}: no {vertex_tag} line: no vertex", path.display())));
    }
    Ok(Read { graph: Graph { poses, fixed, edges: graph_edges }, ids, lines, vertex_line })
}

impl<P: Pose<D> + FromG2o, const D: usize> Read<P, D> {
    /// The file's lines with each vertex's pose as the graph holds it now, written atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut lines = self.lines.clone();
        let tag = lines[self.vertex_line[0]].split_whitespace().next().unwrap_or_default().to_string();
        for (v, &at) in self.vertex_line.iter().enumerate() {
            let values: Vec<String> =
                self.graph.poses[v].to_values().iter().map(|x| format!("{x}")).collect();
            lines[at] = format!("{tag} {} {}", self.ids[v], values.join(" "));
        }
        let mut file = crate::fsutil::AtomicFile::create(path)?;
        for l in &lines {
            writeln!(file, "{l}").at(path)?;
        }
        file.commit().map(|_| ())
    }
}

/// g2o's text of a 3D graph made here (the loops' map): vertices by id, edges, `FIX` lines.
pub fn text_3d(ids: &[i64], graph: &Graph<Se3, 6>) -> String {
    let mut out = String::new();
    for (v, p) in graph.poses.iter().enumerate() {
        let values: Vec<String> = p.to_values().iter().map(|x| format!("{x}")).collect();
        out += &format!("VERTEX_SE3:QUAT {} {}\n", ids[v], values.join(" "));
    }
    for e in &graph.edges {
        let values: Vec<String> = e.measured.to_values().iter().map(|x| format!("{x}")).collect();
        let mut info = Vec::new();
        for i in 0..6 {
            for j in i..6 {
                info.push(format!("{}", e.information[(i, j)]));
            }
        }
        out +=
            &format!("EDGE_SE3:QUAT {} {} {} {}\n", ids[e.from], ids[e.to], values.join(" "), info.join(" "));
    }
    let fixed: Vec<String> =
        (0..graph.poses.len()).filter(|&v| graph.fixed[v]).map(|v| ids[v].to_string()).collect();
    if !fixed.is_empty() {
        out += &format!("FIX {}\n", fixed.join(" "));
    }
    out
}
