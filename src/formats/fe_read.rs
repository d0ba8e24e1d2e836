//! One entry to the FE codes' matrix files: [`read`] by format (DMIG, Abaqus,
//! Harwell–Boeing with or without its mapping), as model files name them.

use crate::error::{Error, Result};
use crate::formats::fe_matrices::{
    FeFormat, FeMatrix, LabelledMatrix, MAX_FE_FILE_BYTES, NumberedMatrix,
};
use crate::formats::harwell_boeing::{mapping_path, parse_harwell_boeing, parse_mapping};
use std::path::Path;

/// Reads matrix `name` (DMIG; ignored for Abaqus and Harwell–Boeing, whose files hold one
/// matrix) of `path` in `format`, size-bounded by [`MAX_FE_FILE_BYTES`]: labelled by the file
/// (DMIG, 5-column Abaqus, Harwell–Boeing with its `.mapping`) or by equation number only
/// (3-column Abaqus, Harwell–Boeing without a mapping: labels from `dofs`).
pub fn read(path: &Path, format: FeFormat, name: Option<&str>) -> Result<FeMatrix> {
    let bytes = crate::formats::files::read_bytes_up_to(path, Some(MAX_FE_FILE_BYTES))?;
    // Free-text lines (titles, comments) may be in any code page: decoded lossily; the
    // parsers check the data lines.
    let text = String::from_utf8_lossy(&bytes);
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
            crate::formats::dmig::parse_dmig(&text, path, name).map(FeMatrix::Labelled)
        }
        FeFormat::Abaqus => crate::formats::abaqus::parse_abaqus(&text, path),
        FeFormat::HarwellBoeing => {
            let hb = parse_harwell_boeing(&text, path)?;
            let map_path = mapping_path(path);
            if !map_path.is_file() {
                return Ok(FeMatrix::Numbered(NumberedMatrix {
                    path: path.to_path_buf(),
                    n: hb.n,
                    entries: hb.entries,
                    kind: format!(
                        "a Harwell-Boeing file whose mapping {} is missing",
                        map_path.display()
                    ),
                }));
            }
            let map_text = crate::formats::files::read_text_bounded(&map_path, MAX_FE_FILE_BYTES)?;
            let labels = parse_mapping(&map_text, &map_path)?;
            if labels.len() != hb.n {
                return Err(Error::Usage(format!(
                    "{} maps {} equations, the matrix {} has {}",
                    map_path.display(),
                    labels.len(),
                    path.display(),
                    hb.n
                )));
            }
            Ok(FeMatrix::Labelled(LabelledMatrix::named_by_file(
                path, labels, hb.entries,
            )))
        }
    }
}
