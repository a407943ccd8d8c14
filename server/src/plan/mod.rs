//! `iogate plan`: what each link's driver plans to ask of its devices, as text.

mod report;

pub use report::{link_plan, render, warnings};
