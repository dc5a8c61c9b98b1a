// Shared by the test files through `#[path]`: small Gmsh 4.1 files written by hand.
#![allow(dead_code)]

/// The unit square as two triangles (the same split as the rectangle generator), with the
/// physical groups `left` (curve x = 0) and `domain` (the surface). `flip` makes the second
/// triangle clockwise (inverted).
pub fn unit_square_msh(flip: bool) -> String {
    let second = if flip { "3 1 4 3" } else { "3 1 3 4" };
    format!(
        r#"$MeshFormat
4.1 0 8
$EndMeshFormat
$PhysicalNames
2
1 1 "left"
2 2 "domain"
$EndPhysicalNames
$Entities
0 1 1 0
1 0 0 0 0 1 0 1 1 0
1 0 0 0 1 1 0 1 2 0
$EndEntities
$Nodes
1 4 1 4
2 1 0 4
1
2
3
4
0 0 0
1 0 0
1 1 0
0 1 0
$EndNodes
$Elements
2 3 1 3
1 1 1 1
1 4 1
2 1 2 2
2 1 2 3
{second}
$EndElements
"#
    )
}
