//! Shape functions and quadrature rules of the linear elements.

use crate::mesh::ElementKind;
use crate::precision::Real;

/// A quadrature point: natural coordinates and weight.
pub struct QuadraturePoint {
    pub xi: [Real; 3],
    pub weight: Real,
}

/// Full-integration rules: 1 point for simplices, 2x2 and 2x2x2 Gauss for Quad4 and Hex8.
pub fn quadrature(kind: ElementKind) -> Vec<QuadraturePoint> {
    let g = 1.0 / (3.0 as Real).sqrt();
    match kind {
        ElementKind::Tri3 => vec![QuadraturePoint { xi: [1.0 / 3.0, 1.0 / 3.0, 0.0], weight: 0.5 }],
        ElementKind::Tet4 => vec![QuadraturePoint { xi: [0.25; 3], weight: 1.0 / 6.0 }],
        ElementKind::Quad4 => {
            let mut q = Vec::new();
            for b in [-g, g] {
                for a in [-g, g] {
                    q.push(QuadraturePoint { xi: [a, b, 0.0], weight: 1.0 });
                }
            }
            q
        }
        ElementKind::Hex8 => {
            let mut q = Vec::new();
            for c in [-g, g] {
                for b in [-g, g] {
                    for a in [-g, g] {
                        q.push(QuadraturePoint { xi: [a, b, c], weight: 1.0 });
                    }
                }
            }
            q
        }
    }
}

const QUAD_CORNERS: [[Real; 2]; 4] = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]];
const HEX_CORNERS: [[Real; 3]; 8] = [[-1.0, -1.0, -1.0], [1.0, -1.0, -1.0], [1.0, 1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]];

/// Shape function values `N_a(ξ)`.
pub fn values(kind: ElementKind, xi: [Real; 3]) -> Vec<Real> {
    let [r, s, t] = xi;
    match kind {
        ElementKind::Tri3 => vec![1.0 - r - s, r, s],
        ElementKind::Tet4 => vec![1.0 - r - s - t, r, s, t],
        ElementKind::Quad4 => QUAD_CORNERS.iter().map(|c| 0.25 * (1.0 + c[0] * r) * (1.0 + c[1] * s)).collect(),
        ElementKind::Hex8 => HEX_CORNERS.iter().map(|c| 0.125 * (1.0 + c[0] * r) * (1.0 + c[1] * s) * (1.0 + c[2] * t)).collect(),
    }
}

/// Shape function derivatives `dN_a/dξ` (third component 0 in 2D).
pub fn gradients(kind: ElementKind, xi: [Real; 3]) -> Vec<[Real; 3]> {
    let [r, s, t] = xi;
    match kind {
        ElementKind::Tri3 => vec![[-1.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        ElementKind::Tet4 => vec![[-1.0, -1.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        ElementKind::Quad4 => QUAD_CORNERS.iter().map(|c| [0.25 * c[0] * (1.0 + c[1] * s), 0.25 * c[1] * (1.0 + c[0] * r), 0.0]).collect(),
        ElementKind::Hex8 => HEX_CORNERS.iter().map(|c| [0.125 * c[0] * (1.0 + c[1] * s) * (1.0 + c[2] * t), 0.125 * c[1] * (1.0 + c[0] * r) * (1.0 + c[2] * t), 0.125 * c[2] * (1.0 + c[0] * r) * (1.0 + c[1] * s)]).collect(),
    }
}
