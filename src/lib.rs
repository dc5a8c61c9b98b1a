//! bifirst: finite-element dynamics of frictional contact and impact between hyperelastic
//! bodies, after Feng, He, Magnain and Cros (2006), "Bi-First".
//!
//! The pipeline follows the folders: [`scene`] -> [`mesh`] -> [`material`] -> [`element`] ->
//! [`assembly`] -> [`solver`] -> [`output`].

pub mod accuracy;
pub mod assembly;
pub mod backend;
pub mod bench;
pub mod contact;
pub mod cpu;
pub mod element;
pub mod gpu;
pub mod grains;
pub mod material;
pub mod mesh;
pub mod output;
pub mod policy;
pub mod precision;
pub mod run;
pub mod scene;
pub mod solver;
pub mod stability;
pub mod sweep;
