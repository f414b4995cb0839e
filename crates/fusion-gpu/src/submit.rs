//! `FusionContext::submit`: one frame's uniforms, bind groups (every binding named by its
//! stage's constant, see [`crate::stages`]) and dispatches in one command buffer, then the
//! copies to the read-back buffers.

use std::sync::mpsc;

use geometry::Image;
use geometry::fusion::ColorProjection;

use crate::context::{
    DepthInput, FusionContext, Pending, Reads, U_BACKPROJECT, U_COLOR, U_HOLE, U_HOLE_CLEAR,
    U_NEAREST, U_PROJECT, U_ZCLEAR, U_ZSCATTER,
};
use crate::stages::holes::EXTENT_WORKGROUP_SIZE;
use crate::stages::{backproject, color, holes, nearest, project, zbuffer};
use crate::{FramePlan, GpuError};

impl FusionContext {
    pub(crate) fn submit(
        &self,
        slot: usize,
        frame: usize,
        depth: DepthInput<'_>,
        color: Option<&Image<[u8; 3]>>,
        proj: &ColorProjection,
        plan: &FramePlan,
    ) -> Result<Pending, GpuError> {
        let missing =
            || self.device_error("preparing a frame", "lookup tables were not uploaded".into());
        let rays = self.depth_rays.as_ref().ok_or_else(missing)?;
        let offsets = self.offsets.as_ref().ok_or_else(missing)?;
        let half_widths = self.half_widths.as_ref().ok_or_else(missing)?;
        let grow_half_widths = self.grow_half_widths.as_ref().ok_or_else(missing)?;
        let s = &self.slots[slot];
        let n = (s.depth_size.0 * s.depth_size.1) as u32;
        let (cw, ch) = (proj.width, proj.height);
        let m = cw * ch;
        let (dx, dy, dstride) = self.grid(n);
        let (cx, cy, cstride) = self.grid(m);
        let (ex, ey, estride) = self.grid_sized(cw + ch, EXTENT_WORKGROUP_SIZE);
        let k = &self.kernels;
        let q = &self.queue;
        let u = &s.uniforms;

        q.write_buffer(
            &u[U_BACKPROJECT],
            0,
            bytemuck::bytes_of(&backproject::Params { size: [n, dstride, 0, 0] }),
        );
        q.write_buffer(
            &u[U_PROJECT],
            0,
            bytemuck::bytes_of(&project::Params::new(proj, n, dstride)),
        );
        q.write_buffer(
            &u[U_ZCLEAR],
            0,
            bytemuck::bytes_of(&zbuffer::Params { size: [cw, ch, m, cstride] }),
        );
        q.write_buffer(
            &u[U_ZSCATTER],
            0,
            bytemuck::bytes_of(&zbuffer::Params { size: [cw, ch, n, dstride] }),
        );
        // A raw frame is decoded in this command buffer, the depth in metres written straight
        // into the slot's depth buffer.
        let decode = match depth {
            DepthInput::Metres(d) => {
                q.write_buffer(&s.depth, 0, bytemuck::cast_slice(d.data()));
                None
            }
            DepthInput::Raw { decoder, raw } => {
                decoder.write_raw(raw);
                Some((decoder, decoder.edge_bind_group(&s.depth)))
            }
        };

        let mut groups = vec![
            (
                &k.zbuffer.clear,
                self.bind(
                    &k.zbuffer.clear,
                    &[(zbuffer::PARAMS, &u[U_ZCLEAR]), (zbuffer::ZBUFFER, &s.zbuffer)],
                ),
                (cx, cy),
            ),
            (
                &k.backproject,
                self.bind(
                    &k.backproject,
                    &[
                        (backproject::PARAMS, &u[U_BACKPROJECT]),
                        (backproject::DEPTH, &s.depth),
                        (backproject::RAYS, &rays.buffer),
                        (backproject::POINTS, &s.points),
                    ],
                ),
                (dx, dy),
            ),
            (
                &k.project,
                self.bind(
                    &k.project,
                    &[
                        (project::PARAMS, &u[U_PROJECT]),
                        (project::POINTS, &s.points),
                        (project::SAMPLES, &s.samples),
                    ],
                ),
                (dx, dy),
            ),
            (
                &k.zbuffer.scatter,
                self.bind(
                    &k.zbuffer.scatter,
                    &[
                        (zbuffer::PARAMS, &u[U_ZSCATTER]),
                        (zbuffer::SAMPLES, &s.samples),
                        (zbuffer::ZBUFFER, &s.zbuffer),
                    ],
                ),
                (dx, dy),
            ),
        ];
        let mut reads =
            Reads { intermediates: plan.read_intermediates, stages: false, color: false };
        if let Some(st) = &plan.stages {
            reads.stages = true;
            let np = nearest::Params {
                size: [cw, ch, m, cstride],
                offsets: [offsets.len, 0, 0, 0],
                jump: [st.depth_jump, 0.0, 0.0, 0.0],
            };
            q.write_buffer(&u[U_NEAREST], 0, bytemuck::bytes_of(&np));
            let radius =
                [half_widths.len.saturating_sub(1), grow_half_widths.len.saturating_sub(1), 0, 0];
            let hc = holes::Params { size: [cw, ch, cw + ch, estride], radius };
            q.write_buffer(&u[U_HOLE_CLEAR], 0, bytemuck::bytes_of(&hc));
            let hp = holes::Params { size: [cw, ch, m, cstride], radius };
            q.write_buffer(&u[U_HOLE], 0, bytemuck::bytes_of(&hp));
            groups.push((
                &k.nearest,
                self.bind(
                    &k.nearest,
                    &[
                        (nearest::PARAMS, &u[U_NEAREST]),
                        (nearest::ZBUFFER, &s.zbuffer),
                        (nearest::OFFSETS, &offsets.buffer),
                        (nearest::DENSE, &s.nearest),
                    ],
                ),
                (cx, cy),
            ));
            groups.push((
                &k.holes.coverage,
                self.bind(
                    &k.holes.coverage,
                    &[
                        (holes::PARAMS, &u[U_HOLE]),
                        (holes::ZBUFFER, &s.zbuffer),
                        (holes::HALF_WIDTH, &half_widths.buffer),
                        (holes::COVERED, &s.covered),
                    ],
                ),
                (cx, cy),
            ));
            groups.push((
                &k.holes.extents,
                self.bind(
                    &k.holes.extents,
                    &[
                        (holes::PARAMS, &u[U_HOLE_CLEAR]),
                        (holes::COVERED, &s.covered),
                        (holes::ROW_EXTENT, &s.row_extent),
                        (holes::COL_EXTENT, &s.col_extent),
                    ],
                ),
                (ex, ey),
            ));
            groups.push((
                &k.holes.core,
                self.bind(
                    &k.holes.core,
                    &[
                        (holes::PARAMS, &u[U_HOLE]),
                        (holes::COVERED, &s.covered),
                        (holes::ROW_EXTENT, &s.row_extent),
                        (holes::COL_EXTENT, &s.col_extent),
                        (holes::CORE, &s.core),
                    ],
                ),
                (cx, cy),
            ));
            groups.push((
                &k.holes.grow,
                self.bind(
                    &k.holes.grow,
                    &[
                        (holes::PARAMS, &u[U_HOLE]),
                        (holes::ZBUFFER, &s.zbuffer),
                        (holes::CORE, &s.core),
                        (holes::GROW_HALF_WIDTH, &grow_half_widths.buffer),
                        (holes::HOLES, &s.holes),
                    ],
                ),
                (cx, cy),
            ));
            if let Some(c) = color {
                reads.color = true;
                write_padded(q, &s.color, bytemuck::cast_slice(c.data()));
                let (tol, on) = st.occlusion_tolerance.map_or((0.0, 0.0), |t| (t, 1.0));
                let cp = color::Params {
                    size: [cw, ch, n, dstride],
                    occlusion: [tol, on, 0.0, 0.0],
                    opaque: [0; 4],
                };
                q.write_buffer(&u[U_COLOR], 0, bytemuck::bytes_of(&cp));
                groups.push((
                    &k.color,
                    self.bind(
                        &k.color,
                        &[
                            (color::PARAMS, &u[U_COLOR]),
                            (color::SAMPLES, &s.samples),
                            (color::COLOR, &s.color),
                            (color::DENSE, &s.nearest),
                            (color::RGBA, &s.rgba),
                        ],
                    ),
                    (dx, dy),
                ));
            }
        }

        let mut enc = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("fusion frame"),
        });
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("fusion"),
                timestamp_writes: None,
            });
            if let Some((decoder, edge_group)) = &decode {
                decoder.record(&mut pass, edge_group);
            }
            for (pipe, group, (gx, gy)) in &groups {
                pass.set_pipeline(pipe);
                pass.set_bind_group(0, group, &[]);
                pass.dispatch_workgroups(*gx, *gy, 1);
            }
        }
        let zbytes = m as u64 * 4;
        let dbytes = n as u64 * 16;
        let mut copies: Vec<(&wgpu::Buffer, &wgpu::Buffer, u64)> =
            vec![(&s.zbuffer, &s.read_z, zbytes)];
        if reads.intermediates {
            copies.push((&s.points, &s.read_points, dbytes));
            copies.push((&s.samples, &s.read_samples, dbytes));
        }
        if reads.stages {
            copies.push((&s.nearest, &s.read_nearest, zbytes));
            copies.push((&s.holes, &s.read_holes, zbytes));
        }
        if reads.color {
            copies.push((&s.rgba, &s.read_rgba, n as u64 * 4));
        }
        for (src, dst, bytes) in &copies {
            enc.copy_buffer_to_buffer(src, 0, dst, 0, *bytes);
        }
        let submission = q.submit([enc.finish()]);
        let (tx, rx) = mpsc::channel();
        for (_, dst, bytes) in &copies {
            let tx = tx.clone();
            dst.map_async(wgpu::MapMode::Read, 0..*bytes, move |r| {
                let _ = tx.send(r);
            });
        }
        self.check_errors("submitting a frame")?;
        Ok(Pending { slot, frame, submission, reads, mapped: rx, maps: copies.len() })
    }
}

/// Writes `bytes` to the start of `buffer`; wgpu copies whole 4-byte words, so a tail of 1-3
/// bytes (an RGB image with an odd pixel count) is padded with zeros.
pub(crate) fn write_padded(queue: &wgpu::Queue, buffer: &wgpu::Buffer, bytes: &[u8]) {
    let aligned = bytes.len() / 4 * 4;
    if aligned > 0 {
        queue.write_buffer(buffer, 0, &bytes[..aligned]);
    }
    if aligned < bytes.len() {
        let mut tail = [0u8; 4];
        tail[..bytes.len() - aligned].copy_from_slice(&bytes[aligned..]);
        queue.write_buffer(buffer, aligned as u64, &tail);
    }
}
