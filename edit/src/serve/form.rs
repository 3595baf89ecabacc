//! An edit request's form: the multipart fields read (with their refusals) and the uploads saved,
//! checked as `matedit edit` would check them and described as a job.

use super::jobs::Work;
use super::upload::{self, Part};
use super::{App, error};
use crate::{Composite, EditRequest};
use anyhow::{Context, Result, bail};
use axum::extract::Multipart;
use axum::http::StatusCode;
use axum::response::Response;
use std::collections::HashMap;
use std::path::PathBuf;

/// The fields of an edit request.
#[derive(Default)]
pub(super) struct Fields {
    pub(super) files: HashMap<&'static str, Part>,
    material: Option<String>,
    /// The object's own material when it is known (`--input-material`).
    input_material: Option<String>,
    optimize: bool,
    /// None: [`Composite::best_for`], as the command line.
    composite: Option<Composite>,
}

pub(super) async fn read_fields(mut mp: Multipart) -> Result<Fields, Response> {
    let mut f = Fields::default();
    loop {
        let field = match mp.next_field().await {
            Ok(Some(field)) => field,
            Ok(None) => break,
            Err(e) => return Err(multipart_error(e)),
        };
        let name = field.name().unwrap_or("").to_string();
        let file_name = field.file_name().unwrap_or("").to_string();
        let bytes = field.bytes().await.map_err(multipart_error)?;
        let text = || String::from_utf8_lossy(&bytes).trim().to_string();
        match name.as_str() {
            "photo" | "mask" | "source" | "source_mask" | "normals" => {
                // An empty file input sends an empty part without a name: as if not given. A
                // file chosen that is empty is an error of its own.
                if bytes.is_empty() && !file_name.is_empty() {
                    return Err(error(
                        StatusCode::UNPROCESSABLE_ENTITY,
                        format!("“{}” is empty (0 bytes)", upload::display_name(&file_name)),
                    ));
                }
                if !bytes.is_empty() {
                    let role = match name.as_str() {
                        "photo" => "photo",
                        "mask" => "mask",
                        "source" => "source",
                        "normals" => "normals",
                        _ => "source_mask",
                    };
                    f.files.insert(role, Part { name: file_name, bytes });
                }
            }
            "material" => f.material = Some(text()).filter(|s| !s.is_empty()),
            "input_material" => f.input_material = Some(text()).filter(|s| !s.is_empty()),
            "optimize" => f.optimize = matches!(text().as_str(), "on" | "true" | "1"),
            "composite" => {
                f.composite = match text().as_str() {
                    "" => None,
                    "structure" => Some(Composite::Structure),
                    "detail" => Some(Composite::Detail),
                    "shading" => Some(Composite::Shading),
                    "delta" => Some(Composite::Delta),
                    "render" => Some(Composite::Render),
                    "ratio" => Some(Composite::Ratio),
                    other => {
                        return Err(error(
                            StatusCode::BAD_REQUEST,
                            format!(
                                "composite “{}”: expected structure, detail, shading, delta, render or ratio",
                                upload::display_name(other)
                            ),
                        ));
                    }
                }
            }
            other => {
                return Err(error(
                    StatusCode::BAD_REQUEST,
                    format!("unexpected field “{}”", upload::display_name(other)),
                ));
            }
        }
    }
    Ok(f)
}

pub(super) fn multipart_error(e: axum::extract::multipart::MultipartError) -> Response {
    let status = e.status();
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        return error(
            status,
            "the upload is larger than this server accepts (see its limits at the top of the page)",
        );
    }
    // A body that breaks off or is malformed on the wire (a bad chunk size, a connection cut)
    // reaches the multipart reader as a stream error, which it reports as the server's (500):
    // it is the request's.
    if status.is_server_error() {
        return error(
            StatusCode::BAD_REQUEST,
            "the upload's body is malformed or was cut off (its transfer encoding could not be read)",
        );
    }
    error(status, format!("the upload could not be read: {}", e.body_text()))
}

/// Saves and checks the uploads (decoding them as `matedit edit` does) and describes the job.
pub(super) fn prepare(app: &App, dir: &std::path::Path, mut f: Fields) -> Result<(Work, Vec<(PathBuf, String)>)> {
    let mut names = Vec::new();
    let mut save = |role: &'static str, f: &mut Fields| -> Result<Option<PathBuf>> {
        match f.files.remove(role) {
            None => Ok(None),
            Some(part) => {
                let (path, shown) = upload::save(dir, role, &part, app.max_pixels)?;
                names.push((path.clone(), shown));
                Ok(Some(path))
            }
        }
    };
    let photo = save("photo", &mut f)?.context("no photo: choose the photo to edit")?;
    let mask = save("mask", &mut f)?;
    let source = save("source", &mut f)?;
    let source_mask = save("source_mask", &mut f)?;
    let normals = save("normals", &mut f)?;
    // Messages name the uploads as the user called them, not by where they were saved.
    let named = |e: anyhow::Error| anyhow::anyhow!(upload::name_uploads(&format!("{e:#}"), &names));
    let check =
        |photo: &std::path::Path, mask: Option<&std::path::Path>| crate::read_photo(photo, mask, None).map_err(named);
    let read = check(&photo, mask.as_deref())?;
    if let Some(n) = &normals {
        // Checked as `matedit edit --normals` checks it: the photo's size, some usable normal on
        // the object, facing the camera.
        crate::normals::load_normals(n, read.photo.width, read.photo.height, &read.coverage).map_err(named)?;
    }
    let optimize = f.optimize.then(|| app.eq6.clone());
    if let Some(spec) = &f.input_material {
        upload::check_material(spec).context("the object's own material")?;
        if optimize.is_some() {
            bail!("the object's own material is held as given: Eq. 6 would change it; give one or the other");
        }
    }
    let composite = f
        .composite
        .unwrap_or(Composite::best_for(f.input_material.is_some(), false));
    let work = match (source, f.material) {
        (Some(_), Some(_)) => bail!("give either a material or a photo to transfer from, not both"),
        (None, None) => bail!("no material: pick a library material or a photo to transfer from"),
        (None, Some(spec)) => {
            upload::check_material(&spec)?;
            if source_mask.is_some() {
                bail!("a mask for the transfer photo was given, but no transfer photo");
            }
            Work::Edit(EditRequest {
                photo,
                mask,
                regions: None,
                materials: vec![(None, spec)],
                relight: None,
                light: None,
                light_level: Default::default(),
                relight_level: Default::default(),
                light_estimate: Default::default(),
                fov_deg: None,
                input_material: f.input_material,
                normals,
                composite: Some(composite),
                range: None,
                optimize,
            })
        }
        (Some(source), None) => {
            check(&source, source_mask.as_deref())?;
            Work::Transfer {
                from: (source, source_mask),
                to: (photo, mask),
                to_material: f.input_material,
                to_normals: normals,
                optimize,
                composite,
            }
        }
    };
    Ok((work, names))
}
