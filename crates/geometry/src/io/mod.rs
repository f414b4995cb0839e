//! File input and output at the edge of the crate. Algorithms elsewhere in `geometry` never
//! open files; these modules do nothing else.
//!
//! | module | reads / writes |
//! | --- | --- |
//! | [`atomic`] | every write: temporary file + rename, [`atomic::StagedDir`] for output folders |
//! | [`mat`] | MATLAB v5 `.mat` files (reader for every numeric class, char, struct, cell; small writer) |
//! | [`course`] | the lab's `synthdata.mat` and `KinectData.mat` → [`crate::Rig`] + images |
//! | [`images`] | colour (PNG/JPEG/TIFF/BMP), depth (16-bit PNG/TIFF mm, float TIFF/EXR m), masks |
//! | [`ply`] | binary PLY point clouds and meshes (colours, `s, t` texture coordinates) |
//! | [`obj`] | OBJ + MTL + PNG texture |
//! | [`rig`] | rig JSON files |

pub mod atomic;
pub mod course;
pub mod images;
pub mod mat;
pub mod obj;
pub mod ply;
pub mod rig;
