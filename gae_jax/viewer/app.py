"""The viewer's app: a viser server whose GUI drives an avatar's FLAME parameters, and a worker
that renders each browser tab's newest state with our jitted renderer (see `gae_jax/view.py`,
the entry point, for what it shows and costs)."""

from __future__ import annotations

import dataclasses
import os
import socket
import sys
import threading
import time

import jax
import numpy as np

from gae_jax.util.fileio import atomic_write_bytes, encode_png
from gae_jax.util.image import to_uint8
from gae_jax.viewer import frames, pose, source

DISPLAYS = ("image", "splats")
BOTH = "side by side"
FREE_CAMERA = "(free)"
NEUTRAL = "(sliders)"
EXPRESSION_RANGE = {True: 1.0, False: 3.0}  # built-in face units / FLAME's PCA directions


def check_port(host: str, port: int) -> None:
    """ValueError when `port` on `host` cannot be bound (viser would silently take the next
    one, and the printed address would not be the one asked for)."""
    if port == 0:
        return
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError as e:
            raise ValueError(f"--port {port}: cannot listen on {host}:{port} ({e.strerror}; "
                             "another viewer? pass another --port, or 0 for a free one)") \
                from None


@dataclasses.dataclass
class _Client:
    """What the viewer keeps per browser tab: the last picture and its render time."""

    image: np.ndarray | None = None
    placed: bool = False  # moved to the frontal rig camera


class Viewer:
    """A running viewer: its `port`, `stop()`, and the GUI's handles and state.

    Everything a render reads (slider values, shown avatar, identity) lives in `values` and the
    GUI handles; one worker thread renders the newest state for every tab that asked, so a
    burst of slider messages costs one render, not one each.
    """

    def __init__(self, viewable: source.Viewable, host: str = "127.0.0.1", port: int = 8080,
                 size: int = 256, display: str = "image", screenshots: str = "screenshots"):
        import viser

        if display not in DISPLAYS:
            raise ValueError(f"--display {display!r}: choose {' or '.join(DISPLAYS)}")
        if size < 16:
            raise ValueError(f"--size {size}: must be >= 16 pixels")
        check_port(host, port)
        self.viewable, self.size, self.display = viewable, int(size), display
        self.screenshots = screenshots
        self.model = jax.device_put(viewable.model)  # where the viewer's data enters the device
        self.avatars = {k: jax.device_put(a) for k, a in viewable.avatars.items()}
        self.values = pose.neutral(viewable.model.num_expr)
        self.capacity: dict = {}
        self._seen: set = set()  # (width, height, show) already compiled
        self.clients: dict = {}
        self.renders = 0
        self._lock = threading.Lock()
        self._dirty: set = set()
        self._wake = threading.Event()
        self._stopping = False
        self._syncing = False
        self._centre = np.asarray(viewable.model.v_template).mean(0)
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = self.server.get_port()
        self.server.scene.set_up_direction("+y")
        # Docked, the panel takes its width from the 3D view instead of covering its right side
        # (where a side-by-side picture's second half would be).
        self.server.gui.main_panel.dock_right()
        self.server.gui.configure_theme(show_share_button=False)  # sharing needs the internet
        self._build_gui()
        self.server.on_client_connect(self._connected)
        self.server.on_client_disconnect(lambda c: self.clients.pop(c.client_id, None))
        self._worker = threading.Thread(target=self._work, name="gae_jax.view", daemon=True)
        self._worker.start()

    # ------------------------------------------------------------------------------- GUI
    def _build_gui(self) -> None:
        v, gui = self.viewable, self.server.gui
        gui.add_markdown(f"**{v.title}**  \n{next(iter(v.avatars.values())).num} Gaussians")
        self.status = gui.add_markdown("render: -")
        labels = list(v.avatars)
        self.show = gui.add_dropdown("Show", tuple(labels + ([BOTH] if len(labels) > 1 else [])),
                                     initial_value=labels[0])
        self.identity = gui.add_dropdown("Identity", tuple(v.shapes), initial_value="A")
        names = [f"camera {i}" for i in range(len(v.w2c))]
        self.camera = gui.add_dropdown("Camera", tuple([FREE_CAMERA] + names),
                                       initial_value=FREE_CAMERA)
        for handle in (self.show, self.identity):
            handle.on_update(lambda _: self._request_all())
        self.camera.on_update(self._camera_chosen)
        with gui.add_folder("Sequence"):
            self.sequence = gui.add_dropdown("Sequence", tuple([NEUTRAL] + list(v.sequences)),
                                             initial_value=NEUTRAL)
            longest = max([s.num_frames for s in v.sequences.values()] + [2])
            self.frame = gui.add_slider("Frame", 0, longest - 1, 1, 0)
            self.playing = gui.add_checkbox("Play", False)
            self.fps = gui.add_slider("Frames per second", 1, 30, 1, 8)
        self.sequence.on_update(self._sequence_chosen)
        self.frame.on_update(lambda _: self._load_frame())
        builtin = bool(v.expr_names) and not v.expr_names[0].startswith("expression ")
        specs = pose.sliders(v.expr_names, v.sequences, EXPRESSION_RANGE[builtin])
        self.sliders = {}
        for group in dict.fromkeys(s.group for s in specs):
            with gui.add_folder(group, expand_by_default=group in ("Expression", "Jaw")):
                for s in (s for s in specs if s.group == group):
                    handle = gui.add_slider(s.label, s.low, s.high, s.step, 0.0)
                    handle.on_update(self._slider_moved(s.key))
                    self.sliders[s.key] = handle
        gui.add_button("Neutral pose").on_click(lambda _: self._set_values(
            pose.neutral(v.model.num_expr)))
        gui.add_button("Screenshot").on_click(lambda e: self.screenshot(e.client))

    def _slider_moved(self, key):
        def moved(_):
            if not self._syncing:
                self.values[key] = float(self.sliders[key].value)
                self._request_all()
        return moved

    def _set_values(self, values: dict) -> None:
        """New slider values (a sequence frame, the neutral pose), shown on the sliders."""
        self.values = dict(values)
        self._syncing = True
        try:
            for key, handle in self.sliders.items():
                handle.value = float(np.clip(values[key], handle.min, handle.max))
        finally:
            self._syncing = False
        self._request_all()

    def _sequence_chosen(self, _) -> None:
        name = self.sequence.value
        if name == NEUTRAL:
            return
        seq = self.viewable.sequences[name]
        if seq.identity in self.viewable.shapes:
            self.identity.value = seq.identity
        self.frame.max = seq.num_frames - 1
        self.frame.value = min(self.frame.value, seq.num_frames - 1)
        self._load_frame()

    def _load_frame(self) -> None:
        name = self.sequence.value
        if name != NEUTRAL:
            seq = self.viewable.sequences[name]
            self._set_values(pose.values_of_frame(seq, min(int(self.frame.value),
                                                           seq.num_frames - 1)))

    def _camera_chosen(self, _) -> None:
        if self.camera.value == FREE_CAMERA:
            return
        for client in self.server.get_clients().values():
            self.use_rig_camera(client, int(self.camera.value.split()[-1]))

    def use_rig_camera(self, client, index: int) -> None:
        """Moves a tab's camera to rig camera `index` (orbiting about the point it looks at)."""
        v = self.viewable
        position, wxyz, fov = frames.view_of_camera(v.intrinsics[index], v.w2c[index], v.height)
        forward = np.asarray(v.w2c[index])[2, :3]
        target = position + forward * max(float(forward @ (self._centre - position)), 1e-3)
        with client.atomic():
            client.camera.fov = fov
            client.camera.position = position
            client.camera.look_at = target

    def _connected(self, client) -> None:
        self.clients[client.client_id] = _Client()
        client.camera.on_update(self._camera_moved)

    def _camera_moved(self, camera) -> None:
        state = self.clients.get(camera.client.client_id)
        if state is None:
            return
        if not state.placed:
            # The browser's first camera message: only now can its camera be moved (viser
            # refuses to before), so the view starts at the frontal rig camera.
            state.placed = True
            self.use_rig_camera(camera.client, frames.front_camera(self.viewable.w2c))
            self._request(camera.client.client_id)
        elif self.display == "image":  # viser's own splat renderer follows the camera itself
            self._request(camera.client.client_id)

    # -------------------------------------------------------------------------- rendering
    def _request(self, client_id) -> None:
        with self._lock:
            self._dirty.add(client_id)
        self._wake.set()

    def _request_all(self) -> None:
        for cid in list(self.clients):
            self._request(cid)

    def current_params(self):
        """FlameParams of the sliders with the chosen identity's shape."""
        identity = self.identity.value
        return pose.params_of_values(self.values, self.viewable.shapes[identity],
                                     self.viewable.model.num_expr,
                                     self.viewable.static_offsets.get(identity))

    def _picture(self, camera, params) -> np.ndarray:
        v = self.viewable
        if self.show.value != BOTH:
            return self._render(self.show.value, camera, params)
        half = frames.side_by_side(camera)
        left, right = (self._render(k, half, params) for k in ("original", "edited"))
        return np.concatenate([_caption(left, "original"), _caption(right, "edited")], axis=1)

    def _render(self, label, camera, params) -> np.ndarray:
        key = (camera.width, camera.height)
        image, self.capacity[key] = frames.render(
            self.model, self.avatars[label], params, camera, self.viewable.background,
            self.viewable.blend, self.capacity.get(key))
        return image

    def _render_client(self, client) -> None:
        params = self.current_params()
        start = time.perf_counter()
        if self.display == "splats":
            label = "edited" if self.show.value == BOTH else self.show.value
            arrays = frames.splat_arrays(self.model, self.avatars[label], params)
            client.scene.add_gaussian_splats("/avatar", arrays.centers, arrays.covariances,
                                             arrays.rgbs, arrays.opacities)
            return
        cam = client.camera
        camera = frames.camera_of_view(cam.position, cam.wxyz, cam.fov, cam.aspect, self.size)
        first = (camera.width, camera.height, self.show.value) not in self._seen
        self._seen.add((camera.width, camera.height, self.show.value))
        image = self._picture(camera, params)
        seconds = time.perf_counter() - start
        client.scene.set_background_image(image, format="jpeg", jpeg_quality=92)
        state = self.clients.get(client.client_id)
        if state is not None:
            state.image = image
        self.status.content = (f"render: {1000 * seconds:.0f} ms "
                               f"({image.shape[1]}x{image.shape[0]}"
                               f"{', first at this size: compiling' if first else ''})")

    def _work(self) -> None:
        next_frame = time.perf_counter()
        while not self._stopping:
            self._wake.wait(timeout=0.02)
            self._wake.clear()
            if self.playing.value and self.sequence.value != NEUTRAL:
                now = time.perf_counter()
                if now >= next_frame:
                    seq = self.viewable.sequences[self.sequence.value]
                    self.frame.value = (int(self.frame.value) + 1) % seq.num_frames
                    next_frame = now + 1.0 / float(self.fps.value)
            with self._lock:
                dirty, self._dirty = self._dirty, set()
            clients = self.server.get_clients()
            for cid in dirty:
                if cid in clients and cid in self.clients:
                    try:
                        self._render_client(clients[cid])
                    except Exception as e:  # keep serving; say what went wrong on the page
                        self.status.content = f"render failed: {type(e).__name__}: {e}"
                        print(f"gae_jax.view: render failed: {e!r}", file=sys.stderr)
            if dirty:
                self.renders += 1

    # ------------------------------------------------------------------------------ misc
    def screenshot(self, client) -> str:
        """Writes the tab's current picture as a PNG into the screenshot folder; its path."""
        state = self.clients.get(getattr(client, "client_id", None)) if client else None
        if state is None or state.image is None:
            if client is not None:
                client.add_notification("Screenshot", "nothing rendered yet",
                                        auto_close_seconds=4.0)
            return ""
        os.makedirs(self.screenshots, exist_ok=True)
        name = time.strftime("view-%Y%m%d-%H%M%S") + f"-{self.renders:05d}.png"
        path = os.path.join(self.screenshots, name)
        atomic_write_bytes(path, encode_png(state.image))
        client.add_notification("Screenshot", f"saved {path}", auto_close_seconds=6.0)
        return path

    def stop(self) -> None:
        self._stopping = True
        self._wake.set()
        self._worker.join(timeout=5.0)
        self.server.stop()


def _caption(image: np.ndarray, text: str) -> np.ndarray:
    import cv2

    out = np.ascontiguousarray(to_uint8(image))
    scale = max(out.shape[0] / 800, 0.3)
    cv2.putText(out, text, (4, int(18 * scale) + 4), cv2.FONT_HERSHEY_SIMPLEX, scale,
                (0, 0, 0), 1, cv2.LINE_AA)
    return out.astype(np.float32) / 255.0
