//! kfuse's file formats, one module per format. The algorithm crates (`geometry`, `calib`,
//! `fusion-gpu`) never open files and carry no codec dependencies; everything that reads or
//! writes bytes on disk lives here. Errors are `geometry::GeometryError` values that always
//! name the file.
//!
//! Rig files of every format have their one home here ([`rig`], [`rig_io`], [`bouguet`]), not
//! in `calib`: the fuse command, the viewer, `kfuse-sequence` and the Python module read rigs
//! without the calibration crate, and the readers need nothing of it (`geometry`, the `.mat`
//! reader of this crate, `serde_yaml_ng`). `calib` writes its results through them.
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
//! | [`rig`] | kfuse's rig JSON files: reading, writing |
//! | [`rig_io`] | rig and camera files of other tools (OpenCV YAML, ROS `camera_info`, iai_kinect2, the sensor's `kinect_params.json`, Bouguet, the lab's `.mat`) imported and exported, `kfuse rig show` |
//! | [`bouguet`] | Bouguet's Camera Calibration Toolbox results (`Calib_Results*.mat`) |
//! | [`sensor_color`] | the Kinect v2's colour JPEG (streamed mirrored) decoded, or flipped without loss (libjpeg-turbo's DCT-domain transform), as the scene is |

#![deny(missing_docs)]

pub mod atomic;
pub mod bouguet;
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
pub mod rig_io;
pub mod sensor_color;
