//! kfuse's file formats, one module per format. The algorithm crates (`geometry`, `calib`,
//! `fusion-gpu`) never open files and carry no codec dependencies; everything that reads or
//! writes bytes on disk lives here. Errors are `geometry::GeometryError` values that always
//! name the file.
//!
//! | module | reads / writes |
//! | --- | --- |
//! | [`atomic`] | every write: temporary file + rename, [`atomic::StagedDir`] for output folders |
//! | [`mat`] | MATLAB v5 `.mat` files (reader for every numeric class, char, struct, cell; small writer) |
//! | [`fused`] | `kfuse fuse`'s output folder (cloud, depth images, mask, meshes, `summary.json`), for the CLI and Python |
//! | [`course`] | the lab's `synthdata.mat` and `KinectData.mat` → [`geometry::Rig`] + images |
//! | [`kinect_data`] | the lab's `KinectData.mat`: rig, colour image, uint16 depth (mm) |
//! | [`image_header`] | image sizes from headers, checked against limits before decoding; JPEG completeness |
//! | [`images`] | colour (PNG/JPEG/TIFF/BMP), depth (16-bit PNG/TIFF mm, float TIFF/EXR m), masks |
//! | [`raster`] | images in their own pixel type and format (undistort keeps both) |
//! | [`provenance`] | the kfuse command that wrote an image, stored in the image (PNG text, JPEG comment, TIFF/EXR software) |
//! | [`ply`] | binary PLY point clouds and meshes (colours, `s, t` texture coordinates) |
//! | [`obj`] | OBJ + MTL + PNG texture |
//! | [`rig`] | rig JSON files |
//! | [`sensor_color`] | the Kinect v2's colour JPEG (streamed mirrored) decoded, or flipped without loss (libjpeg-turbo's DCT-domain transform), as the scene is |

#![deny(missing_docs)]

pub mod atomic;
pub mod course;
pub mod fused;
pub mod image_header;
pub mod images;
pub mod kinect_data;
pub mod mat;
pub mod obj;
pub mod ply;
pub mod provenance;
pub mod raster;
pub mod rig;
pub mod sensor_color;
