//! What the stages share: a frame slot's buffers that pass from one stage to the next
//! ([`FrameBuffers`]), the lookup tables built from the rig and the options ([`Tables`]), and
//! one frame's description handed to every stage's `encode` ([`Work`]). Buffers only one
//! stage uses belong to that stage (`crate::stages`).

use geometry::fusion::{ColorProjection, PixelParams, depth_ray_table, disc_offsets};
use geometry::{CameraModel, DepthKind, Rig};

use crate::gpu::Gpu;
use crate::tables::hole_half_widths;

/// One frame slot's buffers that pass between stages, with their read-back copies.
pub(crate) struct FrameBuffers {
    pub(crate) depth_size: (usize, usize),
    pub(crate) color_size: (usize, usize),
    /// Depth in metres (uploaded, or written by the GPU decoder).
    pub(crate) depth: wgpu::Buffer,
    /// H1: `[X, Y, Z, valid]` per depth pixel.
    pub(crate) points: wgpu::Buffer,
    /// H2: `[u, v, z, valid]` per depth pixel.
    pub(crate) samples: wgpu::Buffer,
    /// H7: the colour-sized z-buffer.
    pub(crate) zbuffer: wgpu::Buffer,
    /// H3: the nearest fill of the colour grid.
    pub(crate) nearest: wgpu::Buffer,
    /// H8: the hole mask (u32 0 / 1 per colour pixel).
    pub(crate) holes: wgpu::Buffer,
    /// The colour image, packed RGB bytes (uploaded).
    pub(crate) color: wgpu::Buffer,
    /// H6: colour and validity per depth pixel.
    pub(crate) rgba: wgpu::Buffer,
    pub(crate) read_z: wgpu::Buffer,
    pub(crate) read_points: wgpu::Buffer,
    pub(crate) read_samples: wgpu::Buffer,
    pub(crate) read_nearest: wgpu::Buffer,
    pub(crate) read_holes: wgpu::Buffer,
    pub(crate) read_rgba: wgpu::Buffer,
}

impl FrameBuffers {
    /// The buffers of frames with these depth and colour sizes.
    pub(crate) fn new(gpu: &Gpu, depth_size: (usize, usize), color_size: (usize, usize)) -> Self {
        let n = (depth_size.0 * depth_size.1) as u64;
        let m = (color_size.0 * color_size.1) as u64;
        Self {
            depth_size,
            color_size,
            depth: gpu.storage("depth", n * 4),
            points: gpu.storage("points", n * 16),
            samples: gpu.storage("samples", n * 16),
            zbuffer: gpu.storage("zbuffer", m * 4),
            nearest: gpu.storage("nearest fill", m * 4),
            holes: gpu.storage("holes", m * 4),
            color: gpu.storage("colour image", m * 3),
            rgba: gpu.storage("colour on depth", n * 4),
            read_z: gpu.read_back("zbuffer read-back", m * 4),
            read_points: gpu.read_back("points read-back", n * 16),
            read_samples: gpu.read_back("samples read-back", n * 16),
            read_nearest: gpu.read_back("nearest read-back", m * 4),
            read_holes: gpu.read_back("holes read-back", m * 4),
            read_rgba: gpu.read_back("colour on depth read-back", n * 4),
        }
    }

    /// `(source, read-back, bytes)` of every output `reads` asks for, the z-buffer first.
    pub(crate) fn copies(&self, reads: Reads) -> Vec<(&wgpu::Buffer, &wgpu::Buffer, u64)> {
        let n = (self.depth_size.0 * self.depth_size.1) as u64;
        let m = (self.color_size.0 * self.color_size.1) as u64;
        let mut copies = vec![(&self.zbuffer, &self.read_z, m * 4)];
        if reads.intermediates {
            copies.push((&self.points, &self.read_points, n * 16));
            copies.push((&self.samples, &self.read_samples, n * 16));
        }
        if reads.stages {
            copies.push((&self.nearest, &self.read_nearest, m * 4));
            copies.push((&self.holes, &self.read_holes, m * 4));
        }
        if reads.color {
            copies.push((&self.rgba, &self.read_rgba, n * 4));
        }
        copies
    }
}

/// What a submitted frame will read back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Reads {
    /// H1 points and H2 samples.
    pub(crate) intermediates: bool,
    /// H3 nearest and the H8 mask.
    pub(crate) stages: bool,
    /// H6 colour on depth.
    pub(crate) color: bool,
}

/// A device buffer built from host data, with the key it was built from.
pub(crate) struct Cached<K> {
    pub(crate) key: K,
    pub(crate) buffer: wgpu::Buffer,
    pub(crate) len: u32,
}

impl<K: PartialEq> Cached<K> {
    /// `slot` holding the table of `key`, rebuilt by `build` when the key differs; true when
    /// it was rebuilt.
    fn ensure<T: bytemuck::Pod>(
        slot: &mut Option<Self>,
        gpu: &Gpu,
        label: &str,
        key: K,
        build: impl FnOnce() -> Vec<T>,
    ) -> bool {
        if slot.as_ref().is_some_and(|c| c.key == key) {
            return false;
        }
        let table = build();
        let buffer = gpu.upload(label, &table);
        *slot = Some(Cached { key, buffer, len: table.len() as u32 });
        true
    }
}

/// The lookup tables of a stream (uploaded once, rebuilt when the rig or a radius changes).
#[derive(Default)]
pub(crate) struct Tables {
    depth_rays: Option<Cached<(CameraModel, DepthKind)>>,
    offsets: Option<Cached<u32>>,
    half_widths: Option<Cached<u32>>,
    grow_half_widths: Option<Cached<u32>>,
    /// Counts rebuilds, so that bind groups made over older tables are known to be stale.
    generation: u64,
}

/// Every table of a frame, present.
pub(crate) struct TableRefs<'a> {
    /// H1: the depth camera's ray per pixel.
    pub(crate) depth_rays: &'a Cached<(CameraModel, DepthKind)>,
    /// H3: the disc offsets in search order (`geometry::fusion::disc_offsets`).
    pub(crate) offsets: &'a Cached<u32>,
    /// H8: half widths of the coverage disc per row offset.
    pub(crate) half_widths: &'a Cached<u32>,
    /// H8: half widths of the growth disc.
    pub(crate) grow_half_widths: &'a Cached<u32>,
}

impl Tables {
    /// Uploads the tables `rig`, `kind` and `stages` need (radii 0 without stages) unless they
    /// are already there.
    pub(crate) fn ensure(
        &mut self,
        gpu: &Gpu,
        rig: &Rig,
        kind: DepthKind,
        stages: Option<&PixelParams>,
    ) {
        let (nearest_r, hole_r, grow_r) =
            stages.map_or((0.0, 0.0, 0.0), |s| (s.radius_px, s.radius_px, s.grow_px));
        let rays = || depth_ray_table(&rig.depth, kind);
        let offsets = || -> Vec<[i32; 2]> {
            disc_offsets(nearest_r).into_iter().map(|(dx, dy, _)| [dx, dy]).collect()
        };
        let changed = [
            Cached::ensure(&mut self.depth_rays, gpu, "depth ray table", (rig.depth, kind), rays),
            Cached::ensure(&mut self.offsets, gpu, "disc offsets", nearest_r.to_bits(), offsets),
            Cached::ensure(
                &mut self.half_widths,
                gpu,
                "hole half widths",
                hole_r.to_bits(),
                || hole_half_widths(hole_r),
            ),
            Cached::ensure(
                &mut self.grow_half_widths,
                gpu,
                "hole grow half widths",
                grow_r.to_bits(),
                || hole_half_widths(grow_r),
            ),
        ];
        if changed.contains(&true) {
            self.generation += 1;
        }
    }

    /// The tables, once [`Tables::ensure`] has run.
    pub(crate) fn get(&self) -> Option<TableRefs<'_>> {
        Some(TableRefs {
            depth_rays: self.depth_rays.as_ref()?,
            offsets: self.offsets.as_ref()?,
            half_widths: self.half_widths.as_ref()?,
            grow_half_widths: self.grow_half_widths.as_ref()?,
        })
    }

    /// Changes with every rebuild of a table.
    pub(crate) fn generation(&self) -> u64 {
        self.generation
    }
}

/// One frame as every stage's `encode` sees it.
pub(crate) struct Work<'a> {
    /// Depth pixels (one invocation each for H1, H2, H7's scatter, H6).
    pub(crate) depth_pixels: u32,
    /// Colour width and height.
    pub(crate) color_size: (u32, u32),
    /// H2's projection into the colour camera.
    pub(crate) proj: &'a ColorProjection,
    /// H3, H8 and H6 when given.
    pub(crate) stages: Option<PixelParams>,
    /// H1's sample rule: the depth range ([`PixelParams::depth_range`]), always given.
    pub(crate) depth_range: geometry::fusion::DepthRange,
    /// Whether the colour image was uploaded (H6 runs with `stages` only).
    pub(crate) color: bool,
    /// The lookup tables (their lengths are in the uniforms).
    pub(crate) tables: TableRefs<'a>,
    /// H7 keeps the z-buffer of the previous submission (no clear): the z-buffer across the
    /// sensors of a rig ([`crate::FusionContext::zbuffer_views`]).
    pub(crate) accumulate_zbuffer: bool,
}

impl Work<'_> {
    /// Colour pixels.
    pub(crate) fn color_pixels(&self) -> u32 {
        self.color_size.0 * self.color_size.1
    }
}
