//! Camera constants: the camera in f64 with the guard-band limits precomputed (the
//! image frustum widened by 30% on each side), and the same camera in f32 for the lane
//! path.

use crate::Camera;

/// Camera in f64 with the guard-band limits precomputed.
pub(super) struct Cam {
    pub(super) r: [[f64; 3]; 3],
    pub(super) t: [f64; 3],
    pub(super) fx: f64,
    pub(super) fy: f64,
    pub(super) cx: f64,
    pub(super) cy: f64,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) lim_x_pos: f64,
    pub(super) lim_x_neg: f64,
    pub(super) lim_y_pos: f64,
    pub(super) lim_y_neg: f64,
}

impl Cam {
    pub(super) fn new(c: &Camera) -> Cam {
        let mut r = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                r[a][b] = c.rotation[a][b] as f64;
            }
        }
        let (fx, fy, cx, cy) = (c.fx as f64, c.fy as f64, c.cx as f64, c.cy as f64);
        let (w, h) = (c.width as f64, c.height as f64);
        let tan_x = 0.5 * w / fx;
        let tan_y = 0.5 * h / fy;
        Cam {
            r,
            t: [
                c.translation[0] as f64,
                c.translation[1] as f64,
                c.translation[2] as f64,
            ],
            fx,
            fy,
            cx,
            cy,
            width: c.width as usize,
            height: c.height as usize,
            lim_x_pos: (w - cx) / fx + 0.3 * tan_x,
            lim_x_neg: cx / fx + 0.3 * tan_x,
            lim_y_pos: (h - cy) / fy + 0.3 * tan_y,
            lim_y_neg: cy / fy + 0.3 * tan_y,
        }
    }
}

/// The same camera in f32 for the lane path.
pub(super) struct CamF {
    pub(super) r: [[f32; 3]; 3],
    pub(super) t: [f32; 3],
    pub(super) fx: f32,
    pub(super) fy: f32,
    pub(super) cx: f32,
    pub(super) cy: f32,
    pub(super) lim_x_pos: f32,
    pub(super) lim_x_neg: f32,
    pub(super) lim_y_pos: f32,
    pub(super) lim_y_neg: f32,
}

impl CamF {
    pub(super) fn new(c: &Cam) -> CamF {
        CamF {
            r: c.r.map(|row| row.map(|v| v as f32)),
            t: c.t.map(|v| v as f32),
            fx: c.fx as f32,
            fy: c.fy as f32,
            cx: c.cx as f32,
            cy: c.cy as f32,
            lim_x_pos: c.lim_x_pos as f32,
            lim_x_neg: c.lim_x_neg as f32,
            lim_y_pos: c.lim_y_pos as f32,
            lim_y_neg: c.lim_y_neg as f32,
        }
    }
}
