//! "Video" for its clients: the image message as the Camera publishes it (a client reads it
//! with a `hng_runtime::control::SliceProviderInput<ImageInfo>`).
//!
//! Images are `ImageInfo` + bytes (RGB8, row-major, top row first). [`check_rgb8`] is the one
//! test of a frame's shape that every consumer applies: a payload whose length is not
//! `width * height * 3`, or a header that does not say `rgb8` with `step = width * 3`, is
//! dropped and counted by the caller.

use hng_runtime::msg::ImageInfo;

/// The "Video" offer's data type.
pub const VIDEO_TYPE: &str = hng_runtime::msg::IMAGE_INFO_TYPE;

/// Why a frame is not a usable RGB8 image, or `None` when it is.
#[must_use]
pub fn check_rgb8(info: &ImageInfo, len: usize) -> Option<String> {
    if info.encoding.as_str() != "rgb8" {
        return Some(format!("encoding {:?}, not rgb8", info.encoding.as_str()));
    }
    if info.step != info.width.saturating_mul(3) {
        return Some(format!("step {} for width {}", info.step, info.width));
    }
    let want = info.step as usize * info.height as usize;
    if len != want || len == 0 {
        return Some(format!(
            "payload of {len} bytes for {}x{} rgb8 ({want} bytes)",
            info.width, info.height
        ));
    }
    None
}

/// The image's horizontal field of view (`ImageInfo` v2 `hfov`, rad), or why it has none
/// usable: a client that turns columns into bearings (the trackers) cannot use the image.
pub fn image_hfov(info: &ImageInfo) -> Result<f64, String> {
    let f = info.hfov;
    if f.is_finite() && f > 0.05 && f < 3.1 {
        Ok(f)
    } else if f == 0.0 {
        Err(
            "the camera gives no field of view (ImageInfo hfov = 0): columns cannot be \
             turned into bearings"
                .into(),
        )
    } else {
        Err(format!(
            "field of view hfov = {f} rad is not in (0.05, 3.1): columns cannot be turned into \
             bearings"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::msg::FrameId;

    #[test]
    fn frames_of_the_wrong_shape_are_named() {
        let info = ImageInfo {
            width: 4,
            height: 2,
            step: 12,
            encoding: FrameId::new("rgb8").unwrap_or_default(),
            ..Default::default()
        };
        assert_eq!(check_rgb8(&info, 24), None);
        assert!(check_rgb8(&info, 23).is_some_and(|e| e.contains("23 bytes")));
        let mono = ImageInfo {
            encoding: FrameId::new("mono8").unwrap_or_default(),
            ..info
        };
        assert!(check_rgb8(&mono, 24).is_some_and(|e| e.contains("mono8")));
        let bad_step = ImageInfo { step: 13, ..info };
        assert!(check_rgb8(&bad_step, 26).is_some());
    }

    #[test]
    fn an_image_without_a_usable_field_of_view_is_named() {
        let mut info = ImageInfo {
            hfov: 1.0,
            ..Default::default()
        };
        assert_eq!(image_hfov(&info), Ok(1.0));
        info.hfov = 0.0;
        assert!(image_hfov(&info).is_err_and(|e| e.contains("no field of view")));
        for bad in [f64::NAN, -1.0, 4.0] {
            info.hfov = bad;
            assert!(
                image_hfov(&info).is_err_and(|e| e.contains("not in")),
                "{bad}"
            );
        }
    }
}
