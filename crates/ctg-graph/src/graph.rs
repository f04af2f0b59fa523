//! The conjugate task graph.

use std::fmt::Write as _;

use crate::{ActionId, CtgError, Result, Vocabulary};

/// One directed, weighted edge of a [`Ctg`]: `to` may follow `from`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    /// The action just taken.
    pub from: ActionId,
    /// The action that may come next.
    pub to: ActionId,
    /// Confidence in `[0, 1]` that the edge exists (1 for demonstrated
    /// edges; probabilities for completed graphs).
    pub weight: f32,
}

/// A conjugate task graph: nodes are the actions of a [`Vocabulary`], a
/// directed edge `a -> b` means "`b` may follow `a`" (the state between two
/// actions is implicit).
///
/// The graph is a dense `n x n` matrix of edge weights in `[0, 1]`
/// (row = from, column = to); `n` is the vocabulary size, `<start>` and
/// `<end>` included. An edge *exists* when its weight is positive; weighted
/// graphs (a completion network's output) become binary with
/// [`Ctg::threshold`].
///
/// Invariants kept by every constructor and mutator: weights are finite and
/// in `[0, 1]`, and the matrix is exactly `n * n`.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "serde", serde(try_from = "CtgRepr", into = "CtgRepr"))]
pub struct Ctg {
    num_nodes: usize,
    weights: Vec<f32>,
}

/// The serialised form of a [`Ctg`]: its size and its edges as
/// `[from, to, weight]` triples, row by row (a graph is sparse: a dense
/// matrix of 10,000 actions would be 10⁸ numbers). Graphs written before
/// the edge list hold the row-major `adjacency` matrix instead, still read.
#[cfg(feature = "serde")]
#[derive(serde::Serialize, serde::Deserialize)]
struct CtgRepr {
    num_nodes: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    edges: Option<Vec<(usize, usize, f32)>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    adjacency: Option<Vec<f32>>,
}

/// The most nodes a serialised [`Ctg`] may declare: the graph is stored as
/// a dense matrix, and a corrupt size must not allocate gigabytes.
pub const MAX_SERIALISED_NODES: usize = 16_384;

#[cfg(feature = "serde")]
impl TryFrom<CtgRepr> for Ctg {
    type Error = CtgError;
    fn try_from(repr: CtgRepr) -> Result<Self> {
        let n = repr.num_nodes;
        if n > MAX_SERIALISED_NODES {
            return Err(CtgError::TooManyNodes {
                n,
                max: MAX_SERIALISED_NODES,
            });
        }
        match (repr.edges, repr.adjacency) {
            (Some(edges), None) => {
                let mut graph = Ctg::empty(n);
                for (from, to, weight) in edges {
                    let (from, to) = (ActionId::new(from), ActionId::new(to));
                    if graph.has_edge(from, to) {
                        return Err(CtgError::DuplicateEdge { from, to });
                    }
                    graph.set_weight(from, to, weight)?;
                }
                Ok(graph)
            }
            (None, Some(adjacency)) => Ctg::from_adjacency(n, adjacency),
            _ => Err(CtgError::GraphFormat(
                "a graph needs exactly one of `edges` and `adjacency`".into(),
            )),
        }
    }
}

#[cfg(feature = "serde")]
impl From<Ctg> for CtgRepr {
    fn from(graph: Ctg) -> Self {
        CtgRepr {
            num_nodes: graph.num_nodes,
            edges: Some(
                graph
                    .edges()
                    .map(|e| (e.from.index(), e.to.index(), e.weight))
                    .collect(),
            ),
            adjacency: None,
        }
    }
}

fn check_weight(from: ActionId, to: ActionId, weight: f32) -> Result<()> {
    if weight.is_finite() && (0.0..=1.0).contains(&weight) {
        Ok(())
    } else {
        Err(CtgError::InvalidWeight { from, to, weight })
    }
}

impl Ctg {
    /// A graph with `num_nodes` nodes and no edges.
    pub fn empty(num_nodes: usize) -> Self {
        Ctg {
            num_nodes,
            weights: vec![0.0; num_nodes * num_nodes],
        }
    }

    /// The graph that allows anything: every node except `<end>` leads to
    /// every node except `<start>` (self-loops included). This is the
    /// "no demo interpreter" ablation's graph.
    pub fn fully_connected(num_nodes: usize) -> Self {
        let mut graph = Ctg::empty(num_nodes);
        for from in 0..num_nodes {
            for to in 0..num_nodes {
                let (from, to) = (ActionId::new(from), ActionId::new(to));
                if from != Vocabulary::END && to != Vocabulary::START {
                    graph.weights[from.index() * num_nodes + to.index()] = 1.0;
                }
            }
        }
        graph
    }

    /// The path graph of one demonstrated action sequence:
    /// `<start> -> a1 -> a2 -> ... -> an -> <end>`.
    ///
    /// Errors if an id is out of range or reserved.
    ///
    /// ```
    /// use ctg_graph::{Ctg, Vocabulary};
    /// let vocab = Vocabulary::new(["pick", "place"]).unwrap();
    /// let path = vocab.parse_sequence("pick place pick place").unwrap();
    /// let graph = Ctg::from_path(vocab.len(), &path).unwrap();
    /// assert!(graph.contains_path(&path));
    /// assert_eq!(graph.num_edges(), 4); // start->pick, pick->place, place->pick, place->end
    /// ```
    pub fn from_path(num_nodes: usize, path: &[ActionId]) -> Result<Self> {
        let mut graph = Ctg::empty(num_nodes);
        graph.add_path(path)?;
        Ok(graph)
    }

    /// The union of the path graphs of several sequences.
    pub fn from_paths<'a, I>(num_nodes: usize, paths: I) -> Result<Self>
    where
        I: IntoIterator<Item = &'a [ActionId]>,
    {
        let mut graph = Ctg::empty(num_nodes);
        for path in paths {
            graph.add_path(path)?;
        }
        Ok(graph)
    }

    /// Adds the edges of `<start> -> path... -> <end>` to this graph.
    pub fn add_path(&mut self, path: &[ActionId]) -> Result<()> {
        for &action in path {
            self.check_node(action)?;
            if Vocabulary::is_reserved(action) {
                let name = if action == Vocabulary::START {
                    Vocabulary::START_NAME
                } else {
                    Vocabulary::END_NAME
                };
                return Err(CtgError::ReservedAction(name));
            }
        }
        self.check_node(Vocabulary::END)?;
        let mut previous = Vocabulary::START;
        for &action in path.iter().chain(std::iter::once(&Vocabulary::END)) {
            self.add_edge(previous, action)?;
            previous = action;
        }
        Ok(())
    }

    /// A graph from a row-major `n x n` weight matrix (row = from).
    pub fn from_adjacency(num_nodes: usize, adjacency: Vec<f32>) -> Result<Self> {
        let expected = num_nodes * num_nodes;
        if adjacency.len() != expected {
            return Err(CtgError::AdjacencyShape {
                got: adjacency.len(),
                expected,
                n: num_nodes,
            });
        }
        for (i, &w) in adjacency.iter().enumerate() {
            check_weight(
                ActionId::new(i / num_nodes.max(1)),
                ActionId::new(i % num_nodes.max(1)),
                w,
            )?;
        }
        Ok(Ctg {
            num_nodes,
            weights: adjacency,
        })
    }

    /// A graph from a matrix given as rows (row = from).
    pub fn from_matrix(rows: &[Vec<f32>]) -> Result<Self> {
        let n = rows.len();
        let mut flat = Vec::with_capacity(n * n);
        for row in rows {
            if row.len() != n {
                return Err(CtgError::AdjacencyShape {
                    got: row.len() * n,
                    expected: n * n,
                    n,
                });
            }
            flat.extend_from_slice(row);
        }
        Ctg::from_adjacency(n, flat)
    }

    /// Number of nodes (the vocabulary size, reserved nodes included).
    pub fn num_nodes(&self) -> usize {
        self.num_nodes
    }

    /// The row-major `n x n` weights (row = from, column = to).
    pub fn adjacency(&self) -> &[f32] {
        &self.weights
    }

    /// The weights as one `Vec` per source node.
    pub fn to_matrix(&self) -> Vec<Vec<f32>> {
        self.weights
            .chunks(self.num_nodes.max(1))
            .take(self.num_nodes)
            .map(<[f32]>::to_vec)
            .collect()
    }

    fn check_node(&self, id: ActionId) -> Result<()> {
        if id.index() < self.num_nodes {
            Ok(())
        } else {
            Err(CtgError::ActionOutOfRange {
                id: id.index(),
                len: self.num_nodes,
            })
        }
    }

    /// Ok if this graph has exactly one node per vocabulary entry.
    pub fn check_vocabulary(&self, vocab: &Vocabulary) -> Result<()> {
        if vocab.len() == self.num_nodes {
            Ok(())
        } else {
            Err(CtgError::SizeMismatch {
                left: self.num_nodes,
                right: vocab.len(),
            })
        }
    }

    /// The weight of `from -> to`; `0.0` (no edge) when either id is out of range.
    pub fn weight(&self, from: ActionId, to: ActionId) -> f32 {
        if from.index() < self.num_nodes && to.index() < self.num_nodes {
            self.weights[from.index() * self.num_nodes + to.index()]
        } else {
            0.0
        }
    }

    /// Whether the edge `from -> to` exists (positive weight).
    pub fn has_edge(&self, from: ActionId, to: ActionId) -> bool {
        self.weight(from, to) > 0.0
    }

    /// Sets the weight of `from -> to` (`0` removes the edge).
    pub fn set_weight(&mut self, from: ActionId, to: ActionId, weight: f32) -> Result<()> {
        self.check_node(from)?;
        self.check_node(to)?;
        check_weight(from, to, weight)?;
        self.weights[from.index() * self.num_nodes + to.index()] = weight;
        Ok(())
    }

    /// Adds `from -> to` with weight 1.
    pub fn add_edge(&mut self, from: ActionId, to: ActionId) -> Result<()> {
        self.set_weight(from, to, 1.0)
    }

    /// Removes `from -> to` (sets its weight to 0).
    pub fn remove_edge(&mut self, from: ActionId, to: ActionId) -> Result<()> {
        self.set_weight(from, to, 0.0)
    }

    /// Nodes that may follow `from`, in id order (empty if out of range).
    pub fn successors(&self, from: ActionId) -> Vec<ActionId> {
        (0..self.num_nodes)
            .map(ActionId::new)
            .filter(|&to| self.has_edge(from, to))
            .collect()
    }

    /// Nodes that `to` may follow, in id order (empty if out of range).
    pub fn predecessors(&self, to: ActionId) -> Vec<ActionId> {
        (0..self.num_nodes)
            .map(ActionId::new)
            .filter(|&from| self.has_edge(from, to))
            .collect()
    }

    /// Every existing edge, row by row.
    pub fn edges(&self) -> impl Iterator<Item = Edge> + '_ {
        let n = self.num_nodes;
        self.weights
            .iter()
            .enumerate()
            .filter(|(_, w)| **w > 0.0)
            .map(move |(i, &weight)| Edge {
                from: ActionId::new(i / n),
                to: ActionId::new(i % n),
                weight,
            })
    }

    /// Number of existing edges.
    pub fn num_edges(&self) -> usize {
        self.weights.iter().filter(|w| **w > 0.0).count()
    }

    /// Whether every weight is 0 or 1.
    pub fn is_binary(&self) -> bool {
        self.weights.iter().all(|&w| w == 0.0 || w == 1.0)
    }

    /// The binary graph of the edges whose weight is at least `threshold`.
    ///
    /// Monotone: a higher threshold never adds an edge. A threshold of 0 or
    /// below keeps only existing edges (weight > 0), never creates one.
    pub fn threshold(&self, threshold: f32) -> Result<Ctg> {
        if threshold.is_nan() {
            return Err(CtgError::InvalidThreshold);
        }
        Ok(Ctg {
            num_nodes: self.num_nodes,
            weights: self
                .weights
                .iter()
                .map(|&w| if w > 0.0 && w >= threshold { 1.0 } else { 0.0 })
                .collect(),
        })
    }

    /// The union of two graphs over the same nodes: the edge-wise maximum
    /// of their weights.
    pub fn union(&self, other: &Ctg) -> Result<Ctg> {
        let mut out = self.clone();
        out.union_with(other)?;
        Ok(out)
    }

    /// In-place [`Ctg::union`].
    pub fn union_with(&mut self, other: &Ctg) -> Result<()> {
        if self.num_nodes != other.num_nodes {
            return Err(CtgError::SizeMismatch {
                left: self.num_nodes,
                right: other.num_nodes,
            });
        }
        for (w, &o) in self.weights.iter_mut().zip(&other.weights) {
            *w = w.max(o);
        }
        Ok(())
    }

    /// Whether every edge of `self` is an edge of `other`.
    pub fn is_subgraph_of(&self, other: &Ctg) -> bool {
        self.num_nodes == other.num_nodes
            && self
                .weights
                .iter()
                .zip(&other.weights)
                .all(|(&a, &b)| a <= 0.0 || b > 0.0)
    }

    /// Whether `<start> -> path... -> <end>` walks only existing edges.
    pub fn contains_path(&self, path: &[ActionId]) -> bool {
        let mut previous = Vocabulary::START;
        for &action in path.iter().chain(std::iter::once(&Vocabulary::END)) {
            if !self.has_edge(previous, action) {
                return false;
            }
            previous = action;
        }
        true
    }

    /// The graph in Graphviz DOT, with the vocabulary's action names as node
    /// ids. Nodes without edges are left out (except `<start>`/`<end>`);
    /// edges with weight below 1 carry their weight as a label.
    ///
    /// ```
    /// use ctg_graph::{Ctg, Vocabulary};
    /// let vocab = Vocabulary::new(["a"]).unwrap();
    /// let graph = Ctg::from_path(vocab.len(), &[vocab.id("a").unwrap()]).unwrap();
    /// let dot = graph.to_dot(&vocab).unwrap();
    /// assert!(dot.contains("\"<start>\" -> \"a\";"));
    /// ```
    pub fn to_dot(&self, vocab: &Vocabulary) -> Result<String> {
        self.check_vocabulary(vocab)?;
        let quote = |id: ActionId| {
            let name = vocab.name(id).unwrap_or("?");
            format!("\"{}\"", name.replace('\\', "\\\\").replace('"', "\\\""))
        };
        let mut out =
            String::from("digraph ctg {\n    rankdir=LR;\n    node [shape=box, style=rounded];\n");
        for id in vocab.ids() {
            let reserved = Vocabulary::is_reserved(id);
            let connected = !self.successors(id).is_empty() || !self.predecessors(id).is_empty();
            if reserved {
                let _ = writeln!(out, "    {} [shape=ellipse];", quote(id));
            } else if connected {
                let _ = writeln!(out, "    {};", quote(id));
            }
        }
        for edge in self.edges() {
            if edge.weight >= 1.0 {
                let _ = writeln!(out, "    {} -> {};", quote(edge.from), quote(edge.to));
            } else {
                let _ = writeln!(
                    out,
                    "    {} -> {} [label=\"{:.2}\", style=dashed];",
                    quote(edge.from),
                    quote(edge.to),
                    edge.weight
                );
            }
        }
        out.push_str("}\n");
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vocab() -> Vocabulary {
        Vocabulary::new(["pick", "place"]).unwrap()
    }

    #[test]
    fn from_path_adds_start_and_end() {
        let v = vocab();
        let path = v.parse_sequence("pick place").unwrap();
        let g = Ctg::from_path(v.len(), &path).unwrap();
        let pick = v.id("pick").unwrap();
        let place = v.id("place").unwrap();
        assert_eq!(g.successors(Vocabulary::START), [pick]);
        assert_eq!(g.successors(pick), [place]);
        assert_eq!(g.successors(place), [Vocabulary::END]);
        assert_eq!(g.predecessors(Vocabulary::END), [place]);
        assert_eq!(g.num_edges(), 3);
    }

    #[test]
    fn from_path_rejects_reserved_and_out_of_range() {
        let v = vocab();
        assert_eq!(
            Ctg::from_path(v.len(), &[Vocabulary::END]),
            Err(CtgError::ReservedAction("<end>"))
        );
        assert_eq!(
            Ctg::from_path(v.len(), &[ActionId::new(9)]),
            Err(CtgError::ActionOutOfRange { id: 9, len: 4 })
        );
    }

    #[test]
    fn union_of_two_demos_has_self_loop() {
        let v = vocab();
        let a = v.parse_sequence("pick place").unwrap();
        let b = v.parse_sequence("pick pick place").unwrap();
        let g = Ctg::from_paths(v.len(), [a.as_slice(), b.as_slice()]).unwrap();
        let pick = v.id("pick").unwrap();
        assert!(g.has_edge(pick, pick));
        assert!(g.contains_path(&a) && g.contains_path(&b));
    }

    #[test]
    fn union_rejects_size_mismatch() {
        assert_eq!(
            Ctg::empty(3).union(&Ctg::empty(4)),
            Err(CtgError::SizeMismatch { left: 3, right: 4 })
        );
    }

    #[test]
    fn adjacency_round_trip_and_validation() {
        let g = Ctg::from_matrix(&[vec![0.0, 0.5], vec![1.0, 0.0]]).unwrap();
        assert_eq!(g.to_matrix(), [vec![0.0, 0.5], vec![1.0, 0.0]]);
        assert_eq!(Ctg::from_adjacency(2, g.adjacency().to_vec()).unwrap(), g);
        assert!(matches!(
            Ctg::from_adjacency(2, vec![0.0; 3]),
            Err(CtgError::AdjacencyShape { .. })
        ));
        assert!(matches!(
            Ctg::from_adjacency(2, vec![0.0, f32::NAN, 0.0, 0.0]),
            Err(CtgError::InvalidWeight { .. })
        ));
        assert!(matches!(
            Ctg::from_matrix(&[vec![0.0, 2.0], vec![0.0, 0.0]]),
            Err(CtgError::InvalidWeight { .. })
        ));
    }

    #[test]
    fn threshold_binarises() {
        let g = Ctg::from_matrix(&[vec![0.2, 0.7], vec![0.0, 1.0]]).unwrap();
        let t = g.threshold(0.5).unwrap();
        assert_eq!(t.to_matrix(), [vec![0.0, 1.0], vec![0.0, 1.0]]);
        assert!(t.is_binary() && !g.is_binary());
        assert_eq!(g.threshold(f32::NAN), Err(CtgError::InvalidThreshold));
        assert_eq!(g.threshold(0.0).unwrap().num_edges(), 3);
    }

    #[test]
    fn fully_connected_never_enters_start_or_leaves_end() {
        let g = Ctg::fully_connected(4);
        assert!(g.predecessors(Vocabulary::START).is_empty());
        assert!(g.successors(Vocabulary::END).is_empty());
        assert_eq!(g.num_edges(), 9);
    }

    #[test]
    fn dot_snapshot() {
        let v = vocab();
        let mut g = Ctg::from_path(v.len(), &v.parse_sequence("pick place").unwrap()).unwrap();
        g.set_weight(v.id("place").unwrap(), v.id("pick").unwrap(), 0.25)
            .unwrap();
        let expected = r#"digraph ctg {
    rankdir=LR;
    node [shape=box, style=rounded];
    "<start>" [shape=ellipse];
    "<end>" [shape=ellipse];
    "pick";
    "place";
    "<start>" -> "pick";
    "pick" -> "place";
    "place" -> "<end>";
    "place" -> "pick" [label="0.25", style=dashed];
}
"#;
        assert_eq!(g.to_dot(&v).unwrap(), expected);
    }

    #[test]
    fn dot_escapes_quotes_and_checks_size() {
        let v = Vocabulary::new(["say \"hi\""]).unwrap();
        let g = Ctg::from_path(v.len(), &[ActionId::new(2)]).unwrap();
        assert!(g.to_dot(&v).unwrap().contains(r#""say \"hi\"""#));
        assert!(Ctg::empty(3).to_dot(&v).is_ok());
        assert!(Ctg::empty(5).to_dot(&v).is_err());
    }
}
