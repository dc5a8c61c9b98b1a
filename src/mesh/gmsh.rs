//! Gmsh `.msh` 4.1 input (ASCII or binary) through the `mshio` crate; other versions are named
//! in the error, before parsing.
//!
//! The mesh is made of the elements of the highest dimension present (Tri3/Quad4 in 2D,
//! Tet4/Hex8 in 3D; one kind per mesh). Node sets come from physical groups of any dimension,
//! named by `$PhysicalNames` (or `physical_<tag>` when unnamed). Nodes no element uses are dropped.
//! A body may take only the elements of one physical group, so that one file holds several
//! bodies (a packing of grains, each a group).

use super::{ElementKind, Mesh};
use crate::precision::Real;
use mshio::mshfile::ElementType;
use std::collections::{BTreeMap, HashMap};

#[derive(Debug, thiserror::Error)]
pub enum GmshError {
    #[error("cannot parse it as MSH: {0}")]
    Parse(String),
    #[error("MSH version {0} is not supported (write version 4.1, e.g. `gmsh -format msh41`)")]
    Version(String),
    #[error("it has no Tri3, Quad4, Tet4 or Hex8 elements (it has {0}); write a first-order mesh (e.g. `gmsh -order 1`)")]
    NoElements(String),
    #[error("it mixes {0} and {1} elements; one kind per mesh is supported")]
    Mixed(&'static str, &'static str),
    #[error("element {element} refers to node tag {tag}, which the file does not define")]
    MissingNode { element: u64, tag: u64 },
    #[error("a 2D mesh must lie in the plane z = 0 (node tag {0} has z = {1})")]
    NotPlanar(u64, Real),
    #[error("it has no physical group `{group}` of {kind} elements (its groups of that dimension: {available})")]
    NoGroup { group: String, kind: &'static str, available: String },
}

fn kind_of(t: ElementType) -> Option<ElementKind> {
    match t {
        ElementType::Tri3 => Some(ElementKind::Tri3),
        ElementType::Qua4 => Some(ElementKind::Quad4),
        ElementType::Tet4 => Some(ElementKind::Tet4),
        ElementType::Hex8 => Some(ElementKind::Hex8),
        _ => None,
    }
}

/// `$PhysicalNames` is not parsed by mshio: read `dim tag "name"` lines ourselves.
fn physical_names(bytes: &[u8]) -> HashMap<(i32, i32), String> {
    let text = String::from_utf8_lossy(bytes);
    let mut names = HashMap::new();
    let Some(start) = text.find("$PhysicalNames") else { return names };
    for line in text[start..].lines().skip(2) {
        if line.starts_with("$End") {
            break;
        }
        let mut parts = line.splitn(3, char::is_whitespace);
        if let (Some(d), Some(t), Some(n)) = (parts.next(), parts.next(), parts.next()) {
            if let (Ok(d), Ok(t)) = (d.parse(), t.parse()) {
                names.insert((d, t), n.trim().trim_matches('"').to_string());
            }
        }
    }
    names
}

/// The version on the line after `$MeshFormat`, read before parsing: mshio rejects older
/// formats with a parse error that does not say why.
fn declared_version(bytes: &[u8]) -> Option<String> {
    let text = String::from_utf8_lossy(&bytes[..bytes.len().min(256)]);
    let mut lines = text.lines().skip_while(|l| l.trim() != "$MeshFormat");
    lines.next()?;
    lines.next()?.split_whitespace().next().map(String::from)
}

/// Every node's coordinates by tag (blocks without tags number their nodes on from the last).
fn node_coordinates(nodes: Option<&mshio::mshfile::Nodes<u64, i32, Real>>) -> HashMap<u64, [Real; 3]> {
    let mut coords = HashMap::new();
    let Some(nodes) = nodes else { return coords };
    let mut next = nodes.min_node_tag;
    for block in &nodes.node_blocks {
        let mut tags: Vec<(u64, usize)> = match &block.node_tags {
            Some(map) => map.iter().map(|(&t, &i)| (t, i)).collect(),
            None => (0..block.nodes.len()).map(|i| (next + i as u64, i)).collect(),
        };
        tags.sort_unstable();
        next += block.nodes.len() as u64;
        for (tag, i) in tags {
            let n = &block.nodes[i];
            coords.insert(tag, [n.x, n.y, n.z]);
        }
    }
    coords
}

/// The physical groups of each entity, by `(dimension, tag)`.
fn entity_groups(entities: Option<&mshio::mshfile::Entities<i32, Real>>) -> HashMap<(i32, i32), Vec<i32>> {
    let mut groups = HashMap::new();
    let Some(ent) = entities else { return groups };
    for p in &ent.points {
        groups.insert((0, p.tag), p.physical_tags.clone());
    }
    for c in &ent.curves {
        groups.insert((1, c.tag), c.physical_tags.clone());
    }
    for s in &ent.surfaces {
        groups.insert((2, s.tag), s.physical_tags.clone());
    }
    for v in &ent.volumes {
        groups.insert((3, v.tag), v.physical_tags.clone());
    }
    groups
}

/// The mesh of a Gmsh file: all elements of its highest dimension, or with `group` only those of
/// that physical group (by name).
pub fn read(bytes: &[u8], group: Option<&str>) -> Result<Mesh, GmshError> {
    if let Some(version) = declared_version(bytes).filter(|v| v.parse::<f64>().map_or(true, |v| (v - 4.1).abs() > 1e-9)) {
        return Err(GmshError::Version(version));
    }
    // mshio can panic on some malformed inputs; a scene error must never be a panic. Its
    // messages are a chain of contexts, one per line, then a hex dump: keep the chain, on one line.
    let parse_error = |e: String| {
        let chain: Vec<&str> = e.lines().map(str::trim).take_while(|l| !l.starts_with("Hex dump")).map(|l| l.trim_end_matches([',', '.'])).filter(|l| !l.is_empty()).collect();
        GmshError::Parse(chain.join(": "))
    };
    let parsed = std::panic::catch_unwind(|| mshio::parse_msh_bytes(bytes).map_err(|e| parse_error(e.to_string()))).map_err(|_| GmshError::Parse("the parser rejected the file".into()))??;
    if (parsed.header.version - 4.1).abs() > 1e-9 {
        return Err(GmshError::Version(parsed.header.version.to_string()));
    }
    let data = parsed.data;
    let coords = node_coordinates(data.nodes.as_ref());
    let names = physical_names(bytes);
    let entity_groups = entity_groups(data.entities.as_ref());
    let group_names = |dim: i32, tag: i32| -> Vec<String> { entity_groups.get(&(dim, tag)).map(Vec::as_slice).unwrap_or_default().iter().map(|p| names.get(&(dim, p.abs())).cloned().unwrap_or_else(|| format!("physical_{}", p.abs()))).collect() };
    let blocks = data.elements.map(|e| e.element_blocks).unwrap_or_default();
    let kind = blocks.iter().filter_map(|b| kind_of(b.element_type)).max_by_key(|k| k.dim()).ok_or_else(|| {
        let mut found: Vec<String> = blocks.iter().map(|b| format!("{:?}", b.element_type)).collect();
        found.dedup();
        GmshError::NoElements(if found.is_empty() { "no elements".into() } else { found.join(", ") })
    })?;
    let mut index: HashMap<u64, u32> = HashMap::new();
    let mut nodes = Vec::new();
    let mut connectivity = Vec::new();
    let chosen = |b: &&mshio::mshfile::ElementBlock<u64, i32>| group.is_none_or(|g| group_names(b.entity_dim, b.entity_tag).iter().any(|n| n == g));
    for b in blocks.iter().filter(|b| kind_of(b.element_type).is_some_and(|k| k.dim() == kind.dim())).filter(chosen) {
        let k = kind_of(b.element_type).expect("filtered");
        if k != kind {
            return Err(GmshError::Mixed(kind.name(), k.name()));
        }
        for e in &b.elements {
            for &tag in &e.nodes {
                let id = match index.get(&tag) {
                    Some(&i) => i,
                    None => {
                        let x = *coords.get(&tag).ok_or(GmshError::MissingNode { element: e.element_tag, tag })?;
                        if kind.dim() == 2 && x[2] != 0.0 {
                            return Err(GmshError::NotPlanar(tag, x[2]));
                        }
                        nodes.push(x);
                        index.insert(tag, nodes.len() as u32 - 1);
                        nodes.len() as u32 - 1
                    }
                };
                connectivity.push(id);
            }
        }
    }
    if let (Some(g), true) = (group, connectivity.is_empty()) {
        let mut available: Vec<String> = blocks.iter().filter(|b| b.entity_dim as usize == kind.dim()).flat_map(|b| group_names(b.entity_dim, b.entity_tag)).collect();
        available.sort();
        available.dedup();
        let available = if available.is_empty() { "none".into() } else { available.join(", ") };
        return Err(GmshError::NoGroup { group: g.to_string(), kind: kind.name(), available });
    }
    // The sets of the groups that touch the mesh (with `group`, many do not).
    let mut node_sets: BTreeMap<String, Vec<u32>> = BTreeMap::new();
    for b in &blocks {
        for name in group_names(b.entity_dim, b.entity_tag) {
            let nodes: Vec<u32> = b.elements.iter().flat_map(|e| e.nodes.iter()).filter_map(|t| index.get(t).copied()).collect();
            if !nodes.is_empty() {
                node_sets.entry(name).or_default().extend(nodes);
            }
        }
    }
    let mut mesh = Mesh { kind, nodes, connectivity, node_sets };
    mesh.finish_sets();
    Ok(mesh)
}
