"""Video-codec compression of rendered frames (``appearance.video_kbps``, issue 8).

Real dense-crowd footage reaches a tracker through a video codec at a modest bit rate, not as
near-lossless stills. :class:`VideoEncoder` writes frames to an MP4 file at a chosen bit rate;
:func:`decode_frames` reads them back through OpenCV, exactly as
:meth:`synth_data.mot.MotSequence.frames` reads a video-only sequence, so the ``img1/`` JPEGs
the writer derives from the decoded frames carry the same codec artefacts as ``video.mp4``.

Codecs: OpenCV's pip wheels carry no H.264 *encoder* (``VideoWriter`` with ``avc1``/``H264``
fails to open: the FFmpeg they bundle is built without libx264), and OpenCV's ``mp4v`` writer
takes no bit rate. Both codecs therefore go through PyAV (``pip install av``; its wheels
bundle FFmpeg with libx264): ``"h264"`` (libx264, preset ``veryfast``, constant bit rate
target) and ``"mpeg4"`` (MPEG-4 part 2, the codec of OpenCV's ``mp4v``). OpenCV decodes both.
Encoding is deterministic: libx264 and FFmpeg's mpeg4 encoder give the same bytes for the same
frames and settings, and the MP4 muxer is told to write bit-exact headers. For libx264 that
takes one thread and :data:`X264_PARAMS` (macroblock-tree rate control off): with it on, some
frame sizes (the calibrated ucf9 seq9's 166x334, for one) gave different bits on every run --
x264's SIMD code then reads memory it never initialised (the same run with ``asm=0`` is
deterministic).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import numpy as np

ENCODERS: dict[str, str] = {"h264": "libx264", "mpeg4": "mpeg4"}
"""``appearance.video_codec`` -> FFmpeg encoder name."""
X264_PRESET: str = "veryfast"
"""libx264 speed preset (surveillance encoders trade quality for speed the same way)."""
GOP_SECONDS: float = 2.0
"""Key-frame interval, seconds."""
X264_PARAMS: str = "mbtree=0"
"""libx264 settings beyond the preset: no macroblock-tree rate control (see the module
docstring: with it, the bits of some frame sizes vary from run to run)."""
ENCODER_THREADS: int = 1
"""Encoder threads: x264's output depends on its thread count, so one thread keeps the bytes
the same on every machine (checksums) at about 40 frames/s for 720p."""


def _require_av() -> Any:
    try:
        import av
    except ImportError:  # pragma: no cover - depends on the environment
        raise ImportError(
            "appearance.video_kbps > 0 needs PyAV for the video codec: "
            "pip install av  (or pip install 'crowdsim[video]')"
        ) from None
    return av


def encoder_available(codec: str) -> bool:
    """Whether ``codec`` (``"h264"`` or ``"mpeg4"``) can be encoded here (PyAV present)."""
    if codec not in ENCODERS:
        raise ValueError(f"video_codec must be one of {tuple(ENCODERS)}, got {codec!r}")
    try:
        av = _require_av()
        av.codec.Codec(ENCODERS[codec], "w")
    except Exception:  # noqa: BLE001 - any failure means "not available"
        return False
    return True


class VideoEncoder:
    """Write ``(H, W, 3)`` uint8 BGR frames to an MP4 file at ``kbps`` kbit/s.

    Parameters
    ----------
    path : path or binary file object
        MP4 file to write (replaced), or a seekable stream such as ``io.BytesIO``.
    width, height : int
        Frame size; odd sizes are not supported by 4:2:0 video and raise ``ValueError``.
    fps : float
        Frame rate.
    kbps : float
        Target bit rate, kbit/s (> 0).
    codec : str
        ``"h264"`` or ``"mpeg4"``.

    Use as a context manager; :meth:`close` flushes the encoder.
    """

    def __init__(
        self,
        path: str | os.PathLike[str] | BinaryIO,
        width: int,
        height: int,
        fps: float,
        kbps: float,
        codec: str = "h264",
    ) -> None:
        from fractions import Fraction

        if codec not in ENCODERS:
            raise ValueError(f"video_codec must be one of {tuple(ENCODERS)}, got {codec!r}")
        if not kbps > 0:
            raise ValueError(f"video_kbps must be > 0, got {kbps!r}")
        if width % 2 or height % 2:
            raise ValueError(f"video frames need even sizes, got {width}x{height}")
        av = _require_av()
        self._av = av
        self.path = path if hasattr(path, "write") else Path(path)
        target = self.path if hasattr(path, "write") else str(self.path)
        self._container = av.open(target, "w", format="mp4", options={"fflags": "+bitexact"})
        rate = Fraction(float(fps)).limit_denominator(1001)
        stream = self._container.add_stream(ENCODERS[codec], rate=rate)
        stream.width, stream.height = int(width), int(height)
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = int(round(kbps * 1000))
        stream.codec_context.gop_size = max(1, int(round(GOP_SECONDS * fps)))
        stream.codec_context.flags |= int(av.codec.context.Flags.bitexact)
        stream.codec_context.thread_count = ENCODER_THREADS
        if codec == "h264":
            stream.options = {"preset": X264_PRESET, "x264-params": X264_PARAMS}
        self._stream = stream
        self.frames = 0

    def write(self, frame: np.ndarray) -> None:
        """Encode one ``(H, W, 3)`` uint8 BGR frame."""
        vf = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="bgr24")
        for packet in self._stream.encode(vf):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and close the file (idempotent)."""
        if self._container is None:
            return
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
        finally:
            self._container.close()
            self._container = None

    def __enter__(self) -> VideoEncoder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def decode_frames(path: str | os.PathLike[str], n_frames: int) -> Iterator[np.ndarray]:
    """Yield ``n_frames`` ``(H, W, 3)`` uint8 BGR frames of a video, decoded by OpenCV."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        for i in range(n_frames):
            ok, img = cap.read()
            if not ok:
                raise ValueError(f"{path}: could not decode frame {i + 1}")
            yield img
    finally:
        cap.release()


def codec_round_trip(
    frames: Iterable[np.ndarray], fps: float, kbps: float, codec: str = "h264"
) -> Iterator[np.ndarray]:
    """Yield every frame after encoding and decoding it through ``codec`` at ``kbps``, in memory.

    For sources that never touch disk: :class:`VideoEncoder` writes the MP4 into a
    ``BytesIO`` (only the compressed stream is held, not the frames), which PyAV then decodes.
    The coded bytes are the ``video.mp4`` the writer makes, byte for byte, and deterministic;
    the frames equal OpenCV's decoding of it up to the YUV -> BGR conversion, which now and
    then rounds a pixel differently by a grey level (tested). All frames are encoded before
    the first comes out.

    (A bare PyAV ``CodecContext`` is no substitute: opened outside a muxer, libx264's
    macroblock-tree rate control gave different bits from run to run.)

    Parameters
    ----------
    frames : iterable of (H, W, 3) uint8 BGR
        Frames of one sequence (even sizes).
    fps, kbps : float
        Frame rate and target bit rate (kbit/s, > 0).
    codec : str
        ``"h264"`` or ``"mpeg4"``.
    """
    import io

    if codec not in ENCODERS:
        raise ValueError(f"video_codec must be one of {tuple(ENCODERS)}, got {codec!r}")
    if not kbps > 0:
        raise ValueError(f"video_kbps must be > 0, got {kbps!r}")
    av = _require_av()
    buf = io.BytesIO()
    enc = None
    try:
        for frame in frames:
            if enc is None:
                h, w = frame.shape[:2]
                enc = VideoEncoder(buf, w, h, fps, kbps, codec)
            enc.write(frame)
    finally:
        if enc is not None:
            enc.close()
    if enc is None:
        return
    buf.seek(0)
    with av.open(buf, "r", format="mp4") as container:
        stream = container.streams.video[0]
        stream.codec_context.thread_count = ENCODER_THREADS  # one core per sequence
        for out in container.decode(stream):
            yield out.to_ndarray(format="bgr24")


def camera_output(
    frames: Iterable[np.ndarray], fps: float, appearance: Any
) -> Iterator[np.ndarray]:
    """The frames a tracker reads from ``generate``'s ``img1/`` JPEGs, made in memory.

    ``generate`` passes rendered frames through the video codec when
    ``appearance.video_kbps > 0`` (:class:`VideoEncoder`, decoded by OpenCV) and then encodes
    them as JPEG at ``appearance.jpeg_quality``. This applies the same two steps to a frame
    stream without touching disk: :func:`codec_round_trip`, then a JPEG encode and decode.
    Without the codec the frames equal the JPEGs read back exactly; with it, up to the rare
    grey-level rounding of :func:`codec_round_trip`'s YUV -> BGR conversion (tested).
    """
    import cv2

    from crowdsim.render import encode_jpeg

    if appearance.video_kbps > 0:
        frames = codec_round_trip(frames, fps, appearance.video_kbps, appearance.video_codec)
    quality = int(appearance.jpeg_quality)
    for frame in frames:
        data = np.frombuffer(encode_jpeg(frame, quality), np.uint8)
        yield cv2.imdecode(data, cv2.IMREAD_COLOR)
