"""Camera rays in normalised scene coordinates, as torch tensors.

Pixel ``(u, v)`` is shot through its centre ``(u + 0.5, v + 0.5)`` (the convention of
:mod:`lift3d.data.cameras`). Pinhole cameras are handled in torch; distorted ones through OpenCV's
undistortion in :meth:`lift3d.data.cameras.Cameras.normalized_coords`.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from lift3d.data.cameras import Cameras, opengl_to_opencv


class RayGenerator:
    """Rays of a set of cameras, expressed in normalised scene coordinates.

    Parameters
    ----------
    cameras : Cameras
        The cameras (OpenGL camera-to-world in *world* units).
    c2w_normalized : np.ndarray
        ``[F, 4, 4]`` the same poses in normalised coordinates (OpenGL axes), see
        :meth:`lift3d.model.normalization.SceneNormalization.c2w_normalized`.
    device : torch.device
    """

    def __init__(self, cameras: Cameras, c2w_normalized: np.ndarray, device: torch.device | str = "cpu"):
        self.cameras = cameras
        self.device = torch.device(device)
        c2w_cv = opengl_to_opencv(c2w_normalized)
        self.rot = torch.as_tensor(c2w_cv[:, :3, :3], dtype=torch.float32, device=self.device)  # [F, 3, 3]
        self.origin = torch.as_tensor(c2w_cv[:, :3, 3], dtype=torch.float32, device=self.device)  # [F, 3]
        self.intr = torch.as_tensor(
            np.stack([cameras.fx, cameras.fy, cameras.cx, cameras.cy], -1), dtype=torch.float32, device=self.device
        )  # [F, 4]

    def rays(self, frame: Tensor, u: Tensor, v: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Rays through pixel centres.

        Parameters
        ----------
        frame : Tensor
            ``[N]`` int64 frame indices (into the cameras given at construction).
        u, v : Tensor
            ``[N]`` pixel column/row (integers, or floats for sub-sampled grids).

        Returns
        -------
        origins : Tensor
            ``[N, 3]``.
        dirs : Tensor
            ``[N, 3]`` unit directions.
        cos_axis : Tensor
            ``[N]`` cosine between each ray and its camera's optical axis (ray distance × cos = z-depth).
        """
        frame = frame.to(self.device)
        uf, vf = u.to(self.device, torch.float32), v.to(self.device, torch.float32)
        if self.cameras.has_distortion:
            x = torch.empty_like(uf)
            y = torch.empty_like(vf)
            for f in torch.unique(frame).tolist():
                sel = (frame == f).nonzero().squeeze(1)
                xs, ys = self.cameras.normalized_coords(f, uf[sel].cpu().numpy(), vf[sel].cpu().numpy())
                x[sel] = torch.as_tensor(xs, dtype=torch.float32, device=self.device)
                y[sel] = torch.as_tensor(ys, dtype=torch.float32, device=self.device)
        else:
            k = self.intr[frame]
            x = (uf + 0.5 - k[:, 2]) / k[:, 0]
            y = (vf + 0.5 - k[:, 3]) / k[:, 1]
        d_cam = torch.stack([x, y, torch.ones_like(x)], -1)
        norm = d_cam.norm(dim=-1, keepdim=True)
        dirs = torch.bmm(self.rot[frame], (d_cam / norm).unsqueeze(-1)).squeeze(-1)
        return self.origin[frame], dirs, (1.0 / norm).squeeze(-1)

    def image_rays(self, i: int, downscale: int = 1) -> tuple[Tensor, Tensor, Tensor, tuple[int, int]]:
        """All rays of frame ``i`` in row-major order (every ``downscale``-th pixel block's centre).

        Returns ``origins``, ``dirs``, ``cos_axis`` flattened and the image shape ``(H', W')``.
        """
        h = int(self.cameras.height[i]) // downscale
        w = int(self.cameras.width[i]) // downscale
        vv, uu = torch.meshgrid(torch.arange(h, device=self.device), torch.arange(w, device=self.device), indexing="ij")
        # Centre of a downscale×downscale block, expressed as a pixel index (centre = index + 0.5).
        off = (downscale - 1) / 2.0
        u = uu.reshape(-1).float() * downscale + off
        v = vv.reshape(-1).float() * downscale + off
        frame = torch.full_like(uu.reshape(-1), i)
        o, d, c = self.rays(frame, u, v)
        return o, d, c, (h, w)
