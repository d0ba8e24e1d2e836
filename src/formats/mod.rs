//! File formats in and out (feature `formats`; the HDF5 files with feature `hdf5`, which
//! links libhdf5 — without it a `.h5` file is refused by [`files::without_hdf5`]): everything nlsim reads — model files, Matrix
//! Market and HDF5 matrices with their binary cache, stepped-sine test data, measured modes,
//! universal files, settings files — and the result files it writes (modes, time histories,
//! FRFs), with the atomic writes and bounded reads they share.
//!
//! Belongs here: parsing and writing bytes, with errors that name the file, line (or HDF5
//! object) and key, and bounds checked before anything is allocated. Does not: plotting, HTML,
//! argument parsing, or running anything (no reduction, no solve) — so the C ABI, a Python
//! package or another program can read and write nlsim's files without `clap`, `plotters`
//! or the command layer (`cargo build -p nlsim --no-default-features --features formats`
//! checks it in `make test`, and that it pulls in no HDF5). Depends only on the numeric crates.
//!
//! | file | format |
//! |---|---|
//! | [`excitation`] | the excitation grammar of `nlsim simulate --excitation` and the Python package |
//! | [`model_file`] | model files (TOML) and the `MODEL` argument (file or built-in name) |
//! | [`matrices`] | Matrix Market and HDF5 (scipy-style CSC) matrices |
//! | [`fe_matrices`] | Nastran DMIG and Abaqus `*MATRIX GENERATE` matrices, labelled by node and DOF |
//! | [`equations`] | the node and DOF of each equation of a numbered matrix: a labels file, an Abaqus `.inp`, an Ansys mapping vector |
//! | [`op4`] | Nastran OUTPUT4 matrices (ASCII, dense and sparse) |
//! | [`cache`] | the memory-mapped binary cache of parsed Matrix Market matrices |
//! | [`test_data`] | stepped-sine test data (CSV and HDF5) |
//! | [`modal_data`] | measured modes (CSV) |
//! | [`uff`] | universal file dataset 58 (FRFs) |
//! | [`settings`] | what the calibration, plan and test files (TOML) share |
//! | [`modes_file`], [`history_file`], [`frf_file`] | result files of `modes`, `simulate`, `frf` |
//! | [`raw_records`] | the raw time records of a virtual test (`nlsim test --raw`) and their step table |
//! | [`candidates`] | the candidates file of a merged calibration batch |
//! | [`files`] | atomic writes, bounded reads, provenance attributes, one-line messages |
//! | [`guard`] | no output over an input: the run's files recorded, output folders written whole under a lock |
//! | [`interrupt`] | stop signals as commands see them: safe points, and the temporaries removed when a run stops at once |

pub mod abaqus;
pub mod cache;
#[cfg(feature = "hdf5")]
pub mod candidates;
pub mod dmig;
pub mod equations;
pub mod excitation;
pub mod fe_matrices;
pub mod fe_read;
pub mod files;
pub mod frf_file;
pub mod guard;
pub mod harwell_boeing;
pub mod history_file;
pub mod interrupt;
pub mod matrices;
pub mod modal_data;
pub mod model_file;
pub mod modes_file;
pub mod op4;
pub mod op4_binary;
pub mod op4_select;
pub mod op4_write;
pub mod raw_records;
pub mod settings;
pub mod test_data;
pub mod time_records;
#[cfg(feature = "hdf5")]
pub mod time_records_h5;
pub mod uff;
pub mod uff55;
pub mod uff_write;
