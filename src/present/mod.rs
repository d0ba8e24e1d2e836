//! Presentation: what a person reads. Model summaries ([`summary`], always built), and with
//! feature `io` the plots as SVG/PNG ([`plot`], their axes [`axis`] and legends
//! [`legend`], the FRF figure [`frf_plot`]), the HTML report
//! with the HDF5 data behind its figures ([`report`]) and the terminal ([`console`]: result
//! lines on stdout that survive a closed pipe, progress lines on stderr only on a terminal).
//!
//! Belongs here: drawing, page layout, wording of summaries, terminal output. Does not: file
//! formats a program reads back (`crate::formats`) or computing results (`crate::commands`
//! and the numeric crates). Depends on `crate::formats` (atomic writes) and the numeric crates
//! only.

#[cfg(feature = "io")]
pub mod axis;
#[cfg(feature = "io")]
pub mod console;
#[cfg(feature = "io")]
pub mod frf_plot;
#[cfg(feature = "io")]
pub mod legend;
#[cfg(feature = "io")]
pub mod plot;
#[cfg(feature = "io")]
pub mod report;
pub mod summary;
