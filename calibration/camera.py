"""Pinhole camera with OpenCV lens distortion, and a group of synchronized cameras.

Conventions (docs/design.md): world right-handed, z up, metres; camera frame OpenCV
(x right, y down, z forward); extrinsics ``x_cam = R @ x_world + t``. Distortion
coefficients in OpenCV order ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tau_x, tau_y]]]])``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import overload

import numpy as np


@dataclass(frozen=True)
class Camera:
    """One calibrated camera.

    Attributes
    ----------
    name : str
        Identifier (e.g. ``"cam_00"``), unique within a rig.
    size : tuple of int
        Image ``(width, height)`` in pixels.
    K : (3, 3) float
        Intrinsic matrix.
    dist : (n,) float
        Distortion coefficients, OpenCV order, n in {4, 5, 8}.
    R : (3, 3) float
        Rotation ``camera_from_world``.
    t : (3,) float
        Translation ``camera_from_world``, metres.
    """

    name: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        dist = np.asarray(self.dist, dtype=float).reshape(-1)
        R = np.asarray(self.R, dtype=float)
        t = np.asarray(self.t, dtype=float).reshape(-1)
        where = f"camera {self.name!r}"
        if K.shape != (3, 3):
            raise ValueError(f"{where}: K must be 3x3, got shape {K.shape}")
        if not (K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == 1 and np.allclose(K[2, :2], 0)):
            raise ValueError(
                f"{where}: K must have positive focal lengths and last row [0, 0, 1], "
                f"got {K.tolist()}"
            )
        if dist.size not in (4, 5, 8, 12, 14):
            raise ValueError(
                f"{where}: distortion must have 4, 5, 8, 12 or 14 values, got {dist.size}"
            )
        if R.shape != (3, 3):
            raise ValueError(f"{where}: R must be 3x3, got shape {R.shape}")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(f"{where}: R must be a rotation (orthonormal, det +1)")
        if t.shape != (3,):
            raise ValueError(f"{where}: t must have 3 values, got shape {t.shape}")
        if len(self.size) != 2 or min(self.size) <= 0:
            shown = tuple(np.asarray(self.size).tolist())  # plain numbers, not np.int64(...)
            raise ValueError(f"{where}: size must be (width, height) > 0, got {shown}")
        for arr in (K, dist, R, t):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{where}: parameters contain NaN or infinity")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))

    def scaled(self, factor: float) -> Camera:
        """The same camera imaging at ``factor`` times the resolution.

        The intrinsics follow the pixel-centre convention: a pixel centre ``x``
        of this image lies at ``x' = (x + 0.5) * factor - 0.5`` in the scaled
        one, so ``f' = f * factor`` and ``c' = (c + 0.5) * factor - 0.5``;
        skew scales with the focal lengths; the distortion (which acts on
        normalized coordinates) and the pose are unchanged. The image size is
        rounded (at least 1 pixel): a world point projects to exactly the
        scaled pixel, whatever the rounding of the size.

        Parameters
        ----------
        factor : float
            Resolution scale, > 0 (0.5: half the width and height).

        Returns
        -------
        Camera
            Same name, extrinsics and distortion; ``size`` about ``factor`` times.

        Raises
        ------
        ValueError
            If ``factor`` is not a positive finite number.
        """
        if not (isinstance(factor, (int, float, np.integer, np.floating)) and 0 < factor < np.inf):
            raise ValueError(
                f"camera {self.name!r}: scale factor must be a positive number, got {factor!r}"
            )
        K = self.K.copy()
        K[:2] *= factor
        K[:2, 2] += 0.5 * factor - 0.5
        w, h = self.size
        size = (max(1, round(w * factor)), max(1, round(h * factor)))
        return Camera(self.name, size, K, self.dist, self.R, self.t)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates (3,)."""
        return -self.R.T @ self.t

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> camera frame (..., 3)."""
        return np.asarray(points, dtype=float) @ self.R.T + self.t

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply the lens model to normalized image coordinates (..., 2) (z = 1 plane).

        The full OpenCV model: radial (rational) ``k1..k6``, tangential ``p1, p2``,
        thin prism ``s1..s4`` (12 or 14 values) and tilted sensor ``tau_x, tau_y``
        (14 values). Complex input is allowed (used for complex-step derivatives).
        """
        xy = np.asarray(xy)
        d = np.zeros(14)
        d[: self.dist.size] = self.dist
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = d[:12]
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        if not d[5:].any():
            # The usual 5-coefficient lens: the same numbers without the zero terms
            # (the likelihood projects ~10^5 points per batch of particles).
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            return np.stack([xd, yd], axis=-1)
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + r2 * (s1 + r2 * s2)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + r2 * (s3 + r2 * s4)
        if d[12] != 0 or d[13] != 0:
            M = tilt_matrix(d[12], d[13])
            w = M[2, 0] * xd + M[2, 1] * yd + M[2, 2]
            xd, yd = (
                (M[0, 0] * xd + M[0, 1] * yd + M[0, 2]) / w,
                (M[1, 0] * xd + M[1, 1] * yd + M[1, 2]) / w,
            )
        return np.stack([xd, yd], axis=-1)

    def project(self, points: np.ndarray, distort: bool = True) -> np.ndarray:
        """Project world points to pixels.

        Parameters
        ----------
        points : (..., 3) float
            World coordinates, metres.
        distort : bool
            Apply lens distortion (False: ideal pinhole).

        Returns
        -------
        (..., 2) float
            Pixel coordinates; points behind the camera give NaN.
        """
        pc = self.to_camera(points)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = pc[..., :2] / z[..., None]
        xy = np.where((z > 1e-9)[..., None], xy, np.nan)
        if distort:
            xy = self.distort_normalized(xy)
        return xy @ self.K[:2, :2].T + self.K[:2, 2]

    @property
    def projection_matrix(self) -> np.ndarray:
        """``K @ [R | t]`` (3, 4): ideal pinhole projection (no distortion)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    def undistort_points(self, pixels: np.ndarray, *, normalized: bool = True) -> np.ndarray:
        """Invert the lens model: observed pixels -> ideal (undistorted) coordinates.

        Solved per point by Newton's method with exact (complex-step) derivatives,
        starting from the distorted point; converges to machine precision within
        the image for realistic lenses (round trip better than 1e-9 px).

        Parameters
        ----------
        pixels : (..., 2) float
            Observed pixel coordinates in the distorted image; NaN allowed.
        normalized : bool
            True: return normalized image coordinates (z = 1 plane, what
            ``distort_normalized`` takes). False: return ideal pinhole pixels
            ``K @ [x, y, 1]`` (the image this camera would see without distortion).

        Returns
        -------
        (..., 2) float
            NaN where the input is NaN or where the lens model cannot be
            inverted (far outside the image, where the model folds over).
        """
        px = np.asarray(pixels, dtype=float)
        if px.ndim == 0 or px.shape[-1] != 2:
            raise ValueError(
                f"camera {self.name!r}: pixels must have shape (..., 2), got {px.shape}"
            )
        A = self.K[:2, :2]
        target = (px - self.K[:2, 2]) @ np.linalg.inv(A).T
        xy = _invert_distortion(self.distort_normalized, target, A)
        if normalized:
            return xy
        return xy @ A.T + self.K[:2, 2]

    def ray(self, pixels: np.ndarray) -> np.ndarray:
        """Unit viewing directions in the world frame (..., 3) through observed pixels (..., 2).

        The rays start at :attr:`center`; NaN where ``undistort_points`` gives NaN.
        """
        xy = self.undistort_points(pixels)
        d_cam = np.concatenate([xy, np.ones_like(xy[..., :1])], axis=-1)
        d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
        return d_cam @ self.R

    def _project_any(self, points: np.ndarray) -> np.ndarray:
        """``project`` without the behind-camera mask; accepts complex input."""
        pc = points @ self.R.T + self.t
        xy = pc[..., :2] / pc[..., 2:3]
        return self.distort_normalized(xy) @ self.K[:2, :2].T + self.K[:2, 2]


def tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """OpenCV's tilted-sensor projection matrix (``computeTiltProjectionMatrix``).

    Parameters
    ----------
    tau_x, tau_y : float
        The sensor's tilt angles (radians): distortion coefficients 12 and 13
        of OpenCV's 14-coefficient model.

    Returns
    -------
    (3, 3) float
        The matrix applied to normalized, distorted image points
        ``(x, y, 1)`` before division by the third coordinate.
    """
    cx, sx = np.cos(tau_x), np.sin(tau_x)
    cy, sy = np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1, 0, 0], [0, cx, sx], [0, -sx, cx]])
    rot_y = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]])
    rot_xy = rot_y @ rot_x
    proj_z = np.array(
        [[rot_xy[2, 2], 0, -rot_xy[0, 2]], [0, rot_xy[2, 2], -rot_xy[1, 2]], [0, 0, 1]]
    )
    return proj_z @ rot_xy


_COMPLEX_STEP = 1e-30


def _invert_distortion(
    distort: Callable[[np.ndarray], np.ndarray],
    target: np.ndarray,
    A: np.ndarray,
    max_iter: int = 30,
    tol_px: float = 1e-6,
) -> np.ndarray:
    """Solve ``distort(xy) = target`` per point by damped Newton.

    ``A`` (2, 2) maps normalized offsets to pixels; it sets the convergence
    threshold ``tol_px`` (pixels) and the "did it converge" test.
    """
    shape = target.shape
    tgt = target.reshape(-1, 2)
    out = np.full_like(tgt, np.nan)
    ok = np.all(np.isfinite(tgt), axis=1)
    x = tgt[ok].copy()
    t = tgt[ok]
    if x.size == 0:
        return out.reshape(shape)

    def residual(z: np.ndarray) -> np.ndarray:
        return np.linalg.norm((distort(z) - t) @ A.T, axis=1)

    e0 = np.array([_COMPLEX_STEP * 1j, 0])
    e1 = np.array([0, _COMPLEX_STEP * 1j])
    with np.errstate(all="ignore"):
        res = residual(x)
        for _ in range(max_iter):
            active = res > 1e-12
            if not np.any(active):
                break
            xa = x[active]
            f = distort(xa) - t[active]
            J = np.stack(
                [distort(xa + e0).imag / _COMPLEX_STEP, distort(xa + e1).imag / _COMPLEX_STEP],
                axis=-1,
            )  # (n, 2 outputs, 2 inputs)
            det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
            step = np.stack(
                [
                    (J[:, 1, 1] * f[:, 0] - J[:, 0, 1] * f[:, 1]) / det,
                    (-J[:, 1, 0] * f[:, 0] + J[:, 0, 0] * f[:, 1]) / det,
                ],
                axis=-1,
            )
            step = np.where(np.isfinite(step), step, 0.0)
            # Backtrack where the full step does not reduce the residual.
            ra = res[active]
            scale = np.ones(len(xa))
            new = xa - step
            rnew = np.linalg.norm((distort(new) - t[active]) @ A.T, axis=1)
            for _ in range(8):
                worse = ~(rnew < ra)
                if not np.any(worse):
                    break
                scale[worse] *= 0.5
                new[worse] = xa[worse] - scale[worse, None] * step[worse]
                rnew[worse] = np.linalg.norm((distort(new[worse]) - t[active][worse]) @ A.T, axis=1)
            improved = rnew < ra
            upd = np.flatnonzero(active)[improved]
            x[upd] = new[improved]
            res[upd] = rnew[improved]
            if not np.any(improved):
                break
    x[~(res <= tol_px)] = np.nan
    out[ok] = x
    return out.reshape(shape)


class CameraGroup:
    """An ordered set of synchronized cameras with unique names (camera axis first).

    Modelled on aniposelib's ``CameraGroup``: projection of world points into
    every camera, triangulation of matched observations, reprojection errors.

    Parameters
    ----------
    cameras : sequence of Camera
        At least one camera; names must be unique.
    """

    def __init__(self, cameras: Sequence[Camera]) -> None:
        cams = tuple(cameras)
        if not cams:
            raise ValueError("CameraGroup needs at least one camera, got none")
        seen: dict[str, int] = {}
        for i, cam in enumerate(cams):
            if not isinstance(cam, Camera):
                raise ValueError(
                    f"CameraGroup: item {i} must be a Camera, got {type(cam).__name__}"
                )
            if cam.name in seen:
                raise ValueError(
                    f"CameraGroup: duplicate camera name {cam.name!r} "
                    f"(items {seen[cam.name]} and {i})"
                )
            seen[cam.name] = i
        self._cameras = cams
        self._index = seen

    # -- container protocol -------------------------------------------------
    @property
    def cameras(self) -> tuple[Camera, ...]:
        """The cameras, in order."""
        return self._cameras

    @property
    def names(self) -> tuple[str, ...]:
        """Camera names, in order."""
        return tuple(cam.name for cam in self._cameras)

    @property
    def sizes(self) -> tuple[tuple[int, int], ...]:
        """Image ``(width, height)`` of every camera, in order."""
        return tuple(cam.size for cam in self._cameras)

    @property
    def same_size(self) -> bool:
        """True when every camera has one image size."""
        return len(set(self.sizes)) <= 1

    def __len__(self) -> int:
        return len(self._cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self._cameras)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    @overload
    def __getitem__(self, key: int | str) -> Camera: ...

    @overload
    def __getitem__(self, key: slice) -> CameraGroup: ...

    def __getitem__(self, key: int | str | slice) -> Camera | CameraGroup:
        """The camera at a position or of a name; a slice gives a sub-group."""
        if isinstance(key, slice):
            return CameraGroup(self._cameras[key])
        if isinstance(key, str):
            return self._cameras[self.index(key)]
        if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
            n = len(self._cameras)
            if not -n <= key < n:
                raise IndexError(f"camera index {key} out of range for {n} cameras")
            return self._cameras[key]
        raise TypeError(f"camera key must be an int, a name or a slice, got {type(key).__name__}")

    def index(self, name: str) -> int:
        """Position of the camera called ``name``."""
        try:
            return self._index[name]
        except KeyError:
            raise KeyError(f"no camera named {name!r}; cameras are {list(self.names)}") from None

    def subset(self, names: Sequence[str]) -> CameraGroup:
        """A new group with the named cameras, in the order given."""
        if isinstance(names, str):
            raise TypeError("subset takes a sequence of names, not a single string")
        missing = [n for n in names if n not in self._index]
        if missing:
            raise KeyError(f"no cameras named {missing}; cameras are {list(self.names)}")
        return CameraGroup([self._cameras[self._index[n]] for n in names])

    def select(self, views: Sequence[int] | np.ndarray) -> CameraGroup:
        """A new group with the cameras at positions ``views``, in that order
        (e.g. the views of a frame with a usable silhouette).

        Parameters
        ----------
        views : sequence of int or (C',) int array
            Camera positions; at least one.
        """
        return CameraGroup([self[int(c)] for c in views])

    def check_masks(self, masks: Sequence[np.ndarray] | np.ndarray) -> list[np.ndarray]:
        """Check per-camera masks against the cameras' image sizes.

        Parameters
        ----------
        masks : (C, H, W) array or sequence of C (H_c, W_c) arrays
            One mask per camera, in camera order, each at its camera's size
            ``(width, height) = camera.size``.

        Returns
        -------
        list of C (H_c, W_c) bool
            The masks as bool arrays (no copy when already bool).

        Raises
        ------
        ValueError
            If the counts differ or a mask's shape is not its camera's size (the
            message names the camera and both sizes).
        """
        if len(masks) != len(self):
            raise ValueError(f"expected one mask per camera ({len(self)}), got {len(masks)}")
        out = []
        for cam, mask in zip(self._cameras, masks, strict=True):
            m = np.asarray(mask, dtype=bool)
            w, h = cam.size
            if m.shape != (h, w):
                got = f"{m.shape[1]}x{m.shape[0]}" if m.ndim == 2 else f"of shape {m.shape}"
                raise ValueError(
                    f"camera {cam.name}: mask is {got} (width x height), camera image is {w}x{h}"
                )
            out.append(m)
        return out

    def scaled(self, factors: float | Sequence[float]) -> CameraGroup:
        """The group with every camera at ``factors`` times its resolution.

        Parameters
        ----------
        factors : float or sequence of C float
            One factor for every camera, or one per camera (camera order);
            see :meth:`Camera.scaled`.
        """
        per_camera = [factors] * len(self) if np.ndim(factors) == 0 else list(factors)
        if len(per_camera) != len(self):
            raise ValueError(
                f"CameraGroup.scaled: expected one factor or {len(self)}, got {len(per_camera)}"
            )
        return CameraGroup(
            [cam.scaled(f) for cam, f in zip(self._cameras, per_camera, strict=True)]
        )

    def __repr__(self) -> str:
        return f"CameraGroup({list(self.names)})"

    @property
    def centers(self) -> np.ndarray:
        """Camera centres in world coordinates (C, 3)."""
        return np.stack([cam.center for cam in self._cameras])

    # -- geometry -------------------------------------------------------------
    def project(self, points: np.ndarray, distort: bool = True) -> np.ndarray:
        """Project world points into every camera.

        Parameters
        ----------
        points : (N, 3) float  (any (..., 3) works)
            World coordinates, metres.

        Returns
        -------
        (C, N, 2) float
            Pixels; NaN for points behind a camera.
        """
        pts = np.asarray(points, dtype=float)
        if pts.ndim == 0 or pts.shape[-1] != 3:
            raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
        return np.stack([cam.project(pts, distort=distort) for cam in self._cameras])

    def _check_pixels(self, pixels: np.ndarray) -> np.ndarray:
        px = np.asarray(pixels, dtype=float)
        if px.ndim != 3 or px.shape[0] != len(self) or px.shape[2] != 2:
            raise ValueError(
                f"pixels must have shape (C, N, 2) with C = {len(self)} cameras, got {px.shape}"
            )
        return px

    def undistort_points(self, pixels: np.ndarray) -> np.ndarray:
        """Observed pixels (C, N, 2) -> normalized undistorted coordinates (C, N, 2)."""
        px = self._check_pixels(pixels)
        return np.stack([cam.undistort_points(p) for cam, p in zip(self._cameras, px, strict=True)])

    def triangulate(
        self,
        pixels: np.ndarray,
        *,
        min_views: int = 2,
        refine: bool = False,
        refine_iterations: int = 10,
    ) -> np.ndarray:
        """Triangulate matched observations.

        Linear DLT on undistorted normalized coordinates (one SVD per point);
        optionally refined by Levenberg-Marquardt on the pixel reprojection error
        (with distortion), which is the maximum-likelihood estimate under
        Gaussian pixel noise.

        Parameters
        ----------
        pixels : (C, N, 2) float
            Observed pixels; NaN (in either coordinate) marks a camera that did
            not see the point.
        min_views : int
            Points seen by fewer cameras come back NaN (at least 2).
        refine : bool
            Run the nonlinear refinement after the DLT.

        Returns
        -------
        (N, 3) float
            World points, metres; NaN where fewer than ``min_views`` views.
        """
        if not isinstance(min_views, (int, np.integer)) or min_views < 2:
            raise ValueError(f"min_views must be an integer >= 2, got {min_views!r}")
        px = self._check_pixels(pixels)
        xy = self.undistort_points(px)  # (C, N, 2)
        valid = np.all(np.isfinite(xy), axis=-1)  # (C, N)
        n_views = valid.sum(axis=0)
        P = np.stack([np.hstack([cam.R, cam.t[:, None]]) for cam in self._cameras])  # (C, 3, 4)
        xy0 = np.where(valid[..., None], xy, 0.0)
        rows_x = xy0[..., 0, None] * P[:, None, 2, :] - P[:, None, 0, :]  # (C, N, 4)
        rows_y = xy0[..., 1, None] * P[:, None, 2, :] - P[:, None, 1, :]
        A = np.concatenate([rows_x, rows_y], axis=0) * np.concatenate([valid, valid])[..., None]
        A = np.transpose(A, (1, 0, 2))  # (N, 2C, 4)
        out = np.full((px.shape[1], 3), np.nan)
        good = n_views >= min_views
        if np.any(good):
            _, _, vt = np.linalg.svd(A[good], full_matrices=False)
            h = vt[:, -1, :]
            with np.errstate(divide="ignore", invalid="ignore"):
                X = h[:, :3] / h[:, 3:]
            out[good] = np.where(np.abs(h[:, 3:]) > 1e-12, X, np.nan)
        if refine:
            out = self._refine_points(out, px, valid, refine_iterations)
        return out

    def _refine_points(
        self, X: np.ndarray, px: np.ndarray, valid: np.ndarray, iterations: int
    ) -> np.ndarray:
        """Levenberg-Marquardt per point on the pixel reprojection error."""
        X = X.copy()
        todo = np.all(np.isfinite(X), axis=1)
        if not np.any(todo):
            return X
        x = X[todo]
        obs = np.where(valid[:, todo, None], px[:, todo], 0.0)  # (C, n, 2)
        w = valid[:, todo, None].astype(float)

        def residuals(pts: np.ndarray) -> np.ndarray:
            r = np.stack([cam._project_any(pts) for cam in self._cameras]) - obs
            return np.where(w > 0, r, 0.0)

        lam = np.full(len(x), 1e-3)
        with np.errstate(all="ignore"):
            r = residuals(x)
            cost = np.sum(r**2, axis=(0, 2))
            for _ in range(iterations):
                J = np.empty((len(self), len(x), 2, 3))
                for k in range(3):
                    e = np.zeros(3, dtype=complex)
                    e[k] = _COMPLEX_STEP * 1j
                    J[..., k] = np.stack(
                        [cam._project_any(x + e).imag / _COMPLEX_STEP for cam in self._cameras]
                    )
                J *= w[..., None]
                JtJ = np.einsum("cnik,cnil->nkl", J, J)
                Jtr = np.einsum("cnik,cni->nk", J, r)
                diag = np.diagonal(JtJ, axis1=1, axis2=2)  # (n, 3)
                H = JtJ + (lam[:, None] * diag + 1e-12)[:, :, None] * np.eye(3)
                step = np.linalg.solve(H, -Jtr[..., None])[..., 0]
                cand = x + step
                r_new = residuals(cand)
                cost_new = np.sum(r_new**2, axis=(0, 2))
                better = np.isfinite(cost_new) & (cost_new < cost)
                x[better] = cand[better]
                r[:, better] = r_new[:, better]
                cost[better] = cost_new[better]
                lam = np.where(better, lam * 0.3, lam * 10.0)
        X[todo] = x
        return X

    def reprojection_error(self, points: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """Pixel distance between projected ``points`` (N, 3) and ``pixels`` (C, N, 2).

        Returns
        -------
        (C, N) float
            Euclidean error in pixels; NaN where the observation is missing, the
            point is NaN, or the point is behind the camera.
        """
        px = self._check_pixels(pixels)
        pts = np.asarray(points, dtype=float)
        if pts.shape != (px.shape[1], 3):
            raise ValueError(
                f"points must have shape (N, 3) with N = {px.shape[1]} (from pixels), "
                f"got {pts.shape}"
            )
        return np.linalg.norm(self.project(pts) - px, axis=-1)
