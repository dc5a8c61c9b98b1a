//! bifirst: finite-element dynamics of frictional contact and impact between hyperelastic
//! bodies, after Feng, He, Magnain and Cros (2006), "Bi-First".
//!
//! The pipeline follows the folders: [`scene`] -> [`mesh`] -> [`material`] -> [`element`] ->
//! [`assembly`] -> [`solver`] -> [`output`].

pub mod assembly;
pub mod backend;
pub mod bench;
pub mod contact;
pub mod cpu;
pub mod element;
pub mod gpu;
pub mod material;
pub mod mesh;
pub mod policy;
pub mod precision;
pub mod scene;
pub mod solver;
pub mod output;
pub mod run;
pub mod sweep;
pub mod accuracy;
pub mod grains;
pub mod stability;
