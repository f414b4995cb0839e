// H8 disocclusion hole mask on the colour grid. CPU twin: geometry::fusion::HoleMasker:
//   occupied(p) = the z-buffer pixel is not empty;
//   covered(p)  = some occupied pixel at (x + dx, y + dy) with |dy| <= R and
//                 |dx| <= half_width[|dy|] (half_width[dy] = floor(sqrt(r² - dy²)), host table);
//   core(p)     = !covered(p) and some covered pixel left and right of p in its row and
//                 above and below it in its column;
//   hole(p)     = !occupied(p) and some core pixel within the disc of radius `grow`
//                 (second half-width table).
// Entry points, in order: `coverage` (covered flags), `extents` (first and last covered pixel
// of every row and column, one invocation per row / column: no atomics, whose contention on
// a few thousand addresses costs ~0.4 s per frame on lavapipe), `core_mask`, `grow`.

struct Params {
    // colour width, colour height, number of pixels (extents: width + height), row stride.
    size: vec4<u32>,
    // R (coverage) = entries of half_width - 1, G (grow) = entries of grow_half_width - 1,
    // unused, unused.
    radius: vec4<u32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> zbuffer: array<u32>;
@group(0) @binding(2) var<storage, read> half_width: array<u32>;
// 1 where covered, 0 elsewhere.
@group(0) @binding(3) var<storage, read_write> covered: array<u32>;
// Per row y: [2y] = first covered x, [2y + 1] = last covered x + 1 (0xFFFFFFFF, 0 = none).
@group(0) @binding(4) var<storage, read_write> row_extent: array<u32>;
// Per column x: [2x] = first covered y, [2x + 1] = last covered y + 1 (0xFFFFFFFF, 0 = none).
@group(0) @binding(5) var<storage, read_write> col_extent: array<u32>;
// 1 for a core pixel, 0 elsewhere.
@group(0) @binding(6) var<storage, read_write> core: array<u32>;
@group(0) @binding(7) var<storage, read> grow_half_width: array<u32>;
// 1 for a hole pixel, 0 elsewhere.
@group(0) @binding(8) var<storage, read_write> holes: array<u32>;

fn is_nan_bits(b: u32) -> bool {
    return (b & 0x7fffffffu) > 0x7f800000u;
}

@compute @workgroup_size(64)
fn extents(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    let w = params.size.x;
    let h = params.size.y;
    if i >= w + h {
        return;
    }
    var first = 0xffffffffu;
    var end = 0u;
    if i < h {
        // Row i.
        for (var x = 0u; x < w; x++) {
            if covered[i * w + x] == 1u {
                first = min(first, x);
                end = x + 1u;
            }
        }
        row_extent[2u * i] = first;
        row_extent[2u * i + 1u] = end;
    } else {
        // Column i - h.
        let x = i - h;
        for (var y = 0u; y < h; y++) {
            if covered[y * w + x] == 1u {
                first = min(first, y);
                end = y + 1u;
            }
        }
        col_extent[2u * x] = first;
        col_extent[2u * x + 1u] = end;
    }
}

@compute @workgroup_size(256)
fn coverage(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    let w = i32(params.size.x);
    let h = i32(params.size.y);
    let x = i32(i % params.size.x);
    let y = i32(i / params.size.x);
    let r = i32(params.radius.x);
    var hit = false;
    for (var dy = -r; dy <= r && !hit; dy++) {
        let sy = y + dy;
        if sy < 0 || sy >= h {
            continue;
        }
        let hw = i32(half_width[u32(abs(dy))]);
        for (var dx = -hw; dx <= hw; dx++) {
            let sx = x + dx;
            if sx >= 0 && sx < w && !is_nan_bits(zbuffer[u32(sy) * params.size.x + u32(sx)]) {
                hit = true;
                break;
            }
        }
    }
    covered[i] = select(0u, 1u, hit);
}

@compute @workgroup_size(256)
fn core_mask(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    let x = i % params.size.x;
    let y = i / params.size.x;
    var hole = 0u;
    if covered[i] == 0u {
        let row_first = row_extent[2u * y];
        let row_end = row_extent[2u * y + 1u];
        let col_first = col_extent[2u * x];
        let col_end = col_extent[2u * x + 1u];
        // first < x < last, with "end" = last + 1 and first = 0xFFFFFFFF when none.
        if row_first != 0xffffffffu && row_first < x && x + 1u < row_end
            && col_first != 0xffffffffu && col_first < y && y + 1u < col_end {
            hole = 1u;
        }
    }
    core[i] = hole;
}

@compute @workgroup_size(256)
fn grow(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.y * params.size.w + gid.x;
    if i >= params.size.z {
        return;
    }
    var hole = 0u;
    if is_nan_bits(zbuffer[i]) {
        let w = i32(params.size.x);
        let h = i32(params.size.y);
        let x = i32(i % params.size.x);
        let y = i32(i / params.size.x);
        let r = i32(params.radius.y);
        for (var dy = -r; dy <= r && hole == 0u; dy++) {
            let sy = y + dy;
            if sy < 0 || sy >= h {
                continue;
            }
            let hw = i32(grow_half_width[u32(abs(dy))]);
            for (var dx = -hw; dx <= hw; dx++) {
                let sx = x + dx;
                if sx >= 0 && sx < w && core[u32(sy) * params.size.x + u32(sx)] == 1u {
                    hole = 1u;
                    break;
                }
            }
        }
    }
    holes[i] = hole;
}
