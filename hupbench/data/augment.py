"""The training augmentation of a batch on its device (an in-plane rotation with the labels turned to match,
then colour jitter), and a loader's frames as model images.

Convention: a positive angle turns the image content counter-clockwise on screen about the principal point
and the camera-frame points by -angle about +z (:mod:`hupbench.input_geometry`).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from hupbench.input_geometry import apply_affine, camera_rotation, inside_input, pixels_to_normalized, rotation_pixel_map


def model_images(images: torch.Tensor, device: torch.device, channels_last: bool = False,
                 depth: torch.Tensor | None = None) -> torch.Tensor:
    """(B, C, S, S) float32 model images on ``device`` (channels_last memory format if asked): a loader's
    (B, S, S, 3) uint8 RGB frames, moved as bytes (a quarter of the float traffic), as RGB in [0, 1], followed
    by ``depth`` (B, S, S) float32 metres (the depth channel) when given; model images pass through."""
    images = images.to(device, non_blocking=True)
    if images.dtype == torch.uint8:
        images = images.permute(0, 3, 1, 2).float().div_(255.0)  # (B, S, S, 3) -> (B, 3, S, S)
    if depth is not None:
        images = torch.cat([images, depth.to(device, torch.float32, non_blocking=True)[:, None]], dim=1)
    return images.contiguous(memory_format=torch.channels_last if channels_last else torch.contiguous_format)


class BatchAugment:
    """The training augmentation of :class:`hupbench.data.ReaderConfig`'s ``rotate_deg``, ``photometric``
    and ``seed``.

    Rotation: by a uniform angle in [-rotate_deg, rotate_deg] about the principal point (bilinear, reflected
    border). Colour jitter of strength p: brightness, contrast and saturation factors in [1 - 0.4 p,
    1 + 0.4 p] and a hue shift in [-0.05 p, 0.05 p] turns, per sample, in an order drawn once per batch
    (kornia's ColorJiggle ranges).

    Call with a batch of :class:`hupbench.data.loaders.FrameBatches` on the device and the epoch: "image"
    becomes the (B, C, S, S) float32 model images (a "depth" entry becomes their fourth channel: turned to the
    nearest pixel with 0, no surface, beyond the border, and not jittered), the keypoints and "visible" turn
    with it. A "seg" entry, (B, S, S) ``SEGMENT_CLASSES`` indices, turns as the depth does (nearest pixel, class 0
    "other" beyond the border), is never jittered, and comes back (B, S, S) int64 on the device. Draws depend
    only on (seed, epoch, item index), so a run and its resume see the same augmentation in any batch
    composition (but the jitter's operation order, drawn from the batch's first item).
    """

    def __init__(self, config) -> None:
        self.rotate_deg, self.photometric, self.seed = config.rotate_deg, config.photometric, config.seed

    def draws(self, indices, epoch: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-item (angles (B,) radians, jitter factors (B, 4): brightness, contrast, saturation, hue)."""
        angles = np.zeros(len(indices))
        factors = np.tile([1.0, 1.0, 1.0, 0.0], (len(indices), 1))
        p = self.photometric
        for row, index in enumerate(np.asarray(indices, dtype=np.int64).tolist()):
            if self.rotate_deg > 0:
                rng = np.random.default_rng([self.seed, int(epoch), index])
                angles[row] = np.deg2rad(rng.uniform(-self.rotate_deg, self.rotate_deg))
            if p > 0:
                jitter = np.random.default_rng([self.seed, int(epoch), index, 1])
                factors[row, :3] = jitter.uniform(1.0 - 0.4 * p, 1.0 + 0.4 * p, size=3)
                factors[row, 3] = jitter.uniform(-0.05 * p, 0.05 * p)
        return angles, factors

    def __call__(self, batch: dict, epoch: int) -> dict:
        out = dict(batch)
        images = model_images(batch["image"], batch["image"].device, depth=out.pop("depth", None))
        rgb, depth = images[:, :3], images[:, 3:]
        device = images.device
        seg = out.pop("seg", None)
        seg = None if seg is None else seg.to(device, torch.int64, non_blocking=True)            # (B, S, S)
        indices = batch["index"].cpu().numpy()
        angles, factors = self.draws(indices, epoch)
        if self.rotate_deg > 0:
            import kornia

            size = images.shape[-1]
            maps = rotation_pixel_map(angles, batch["K"].cpu().double().numpy()[:, :2, 2])    # (B, 3, 3) pixels
            affine = torch.from_numpy(maps[:, :2]).to(device, torch.float32)
            rgb = kornia.geometry.transform.warp_affine(rgb, affine, (size, size), mode="bilinear",
                                                        padding_mode="reflection", align_corners=True)
            if depth.shape[1]:
                depth = kornia.geometry.transform.warp_affine(depth, affine, (size, size), mode="nearest",
                                                              padding_mode="zeros", align_corners=True)
            if seg is not None:  # class indices are exact in float32; zeros padding is class 0, "other"
                seg = kornia.geometry.transform.warp_affine(seg[:, None].float(), affine, (size, size), mode="nearest",
                                                            padding_mode="zeros", align_corners=True)[:, 0].long()
            uv = apply_affine(maps, batch["keypoints_2d_px"].cpu().numpy())                     # (B, 29, 2)
            points = batch["keypoints_3d"].cpu().double().numpy() @ camera_rotation(angles).transpose(0, 2, 1)
            turned = {"keypoints_3d": points, "keypoints_2d_px": uv, "keypoints_2d": pixels_to_normalized(uv, size)}
            out.update({name: torch.from_numpy(value).to(device, torch.float32) for name, value in turned.items()})
            out["visible"] = batch["visible"] & torch.from_numpy(inside_input(uv, size)).to(device)
        if self.photometric > 0:
            rgb = self._jitter(rgb, torch.from_numpy(factors).to(device, rgb.dtype),
                               np.random.default_rng([self.seed, int(epoch), int(indices[0]), 2]).permutation(4))
        out["image"] = torch.cat([rgb, depth], dim=1) if depth.shape[1] else rgb
        if seg is not None:
            out["seg"] = seg
        return out

    @staticmethod
    def _jitter(images: torch.Tensor, factors: torch.Tensor, order: np.ndarray) -> torch.Tensor:
        from kornia.enhance import adjust_brightness, adjust_contrast, adjust_hue, adjust_saturation

        steps = (lambda x, f: adjust_brightness(x, f - 1.0), adjust_contrast, adjust_saturation,
                 lambda x, f: adjust_hue(x, f * 2.0 * math.pi))
        images = images.clamp(0.0, 1.0)
        for step in order.tolist():
            images = steps[step](images, factors[:, step])
        return images.clamp(0.0, 1.0)
