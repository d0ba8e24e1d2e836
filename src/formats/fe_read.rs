//! One entry to the FE codes' labelled matrix files: [`read`] by format (DMIG, Abaqus,
//! Harwell–Boeing with its mapping), as model files name them.

use crate::error::{Error, Result};
use crate::formats::fe_matrices::{FeFormat, LabelledMatrix, MAX_FE_FILE_BYTES};
use crate::formats::harwell_boeing::{mapping_path, parse_harwell_boeing, parse_mapping};
use std::path::Path;

/// Reads matrix `name` (DMIG; ignored for Abaqus, whose files hold one matrix) of `path` in
/// `format`, size-bounded by [`MAX_FE_FILE_BYTES`].
pub fn read(path: &Path, format: FeFormat, name: Option<&str>) -> Result<LabelledMatrix> {
    let text = crate::formats::files::read_text_bounded(path, MAX_FE_FILE_BYTES)?;
    match format {
        FeFormat::Dmig => {
            let name = name.ok_or_else(|| {
                Error::Usage(format!(
                    "{}: a DMIG file can hold several matrices: name one, e.g. \
                     \"{}:KAAX\"",
                    path.display(),
                    path.display()
                ))
            })?;
            crate::formats::dmig::parse_dmig(&text, path, name)
        }
        FeFormat::Abaqus => crate::formats::abaqus::parse_abaqus(&text, path),
        FeFormat::HarwellBoeing => {
            let map_path = mapping_path(path);
            if !map_path.is_file() {
                return Err(Error::Usage(format!(
                    "{}: a Harwell-Boeing file carries no DOF labels: nlsim reads them from \
                     {}, which is missing (write it with HBMAT, ..., Mapping = YES)",
                    path.display(),
                    map_path.display()
                )));
            }
            let map_text = crate::formats::files::read_text_bounded(&map_path, MAX_FE_FILE_BYTES)?;
            let labels = parse_mapping(&map_text, &map_path)?;
            let hb = parse_harwell_boeing(&text, path)?;
            if labels.len() != hb.n {
                return Err(Error::Usage(format!(
                    "{} maps {} equations, the matrix {} has {}",
                    map_path.display(),
                    labels.len(),
                    path.display(),
                    hb.n
                )));
            }
            Ok(LabelledMatrix::named_by_file(path, labels, hb.entries))
        }
    }
}
