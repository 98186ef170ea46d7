"""progskin — Python binding of the progskin streaming client (ctypes over
libprogskin_c.so, the C API of capi/progskin.h; no compiled extension).
docs/bindings.md describes the contract.

    import progskin
    c = progskin.Client(pin_sha256="AB:CD:...", cache_dir="/tmp/cache")
    c.connect("127.0.0.1", 7777)
    while True:
        c.update()                       # once per frame, never blocks
        for e in c.events(): print(e)
        for ch in c.characters():        # palette: 12 floats per bone
            draw(ch.asset, ch.position, ch.rotation, ch.palette)

The library is found by the environment variable PROGSKIN_C_LIBRARY (a
path), else by the system's search (ctypes.util.find_library("progskin_c"),
e.g. after installing progskin, with LD_LIBRARY_PATH when not in a system
directory). Errors raise progskin.Error (status and message). A Client is
used from one thread at a time. Palettes are views into the library's
memory, valid until the next update(); copy them (list(ch.palette)) to keep.
"""
import ctypes
import ctypes.util
import os

__all__ = ["Error", "Client", "Character", "Event", "Asset", "load_library", "now", "version",
           "State", "EventType"]

OK, EMPTY, NOT_READY = 0, 1, 2


class State:
    IDLE, CONNECTING, STREAMING, CLOSED, FAILED = range(5)


class EventType:
    CONNECTED, ASSET_READY, CHARACTER_ADDED, CHARACTER_REMOVED, SPAWNED, SPAWN_REFUSED, CLOSED, FAILED, \
        ASSET_FAILED, FAILED_OVER = range(1, 11)
    NAMES = {1: "connected", 2: "asset_ready", 3: "character_added", 4: "character_removed", 5: "spawned",
             6: "spawn_refused", 7: "closed", 8: "failed", 9: "asset_failed", 10: "failed_over"}


class Error(Exception):
    """A call of the C API returned an error status; .status and .message say which and why."""

    def __init__(self, status, message):
        super().__init__("%s: %s" % (_lib().psk_status_name(status).decode(), message))
        self.status, self.message = status, message


c_float_p = ctypes.POINTER(ctypes.c_float)


class _Config(ctypes.Structure):
    _fields_ = [("name", ctypes.c_char_p), ("token", ctypes.c_char_p), ("cache_dir", ctypes.c_char_p),
                ("ca_file", ctypes.c_char_p), ("pin_sha256", ctypes.c_char_p), ("udp_via_host", ctypes.c_char_p),
                ("max_kbps", ctypes.c_double), ("delay_ms", ctypes.c_double), ("max_delay_ms", ctypes.c_double),
                ("connect_timeout", ctypes.c_double), ("stream_timeout", ctypes.c_double),
                ("tls", ctypes.c_int32), ("insecure", ctypes.c_int32), ("blend_frames", ctypes.c_int32),
                ("snap_to_ticks", ctypes.c_int32), ("udp_via_port", ctypes.c_int32),
                ("protocol_version", ctypes.c_int32)]


class _Event(ctypes.Structure):
    _fields_ = [("text", ctypes.c_char_p), ("type", ctypes.c_int32), ("instance", ctypes.c_int32),
                ("asset", ctypes.c_int32), ("handle", ctypes.c_int32)]


class _Character(ctypes.Structure):
    _fields_ = [("position", ctypes.c_double * 3), ("display_tick", ctypes.c_double), ("palette", c_float_p),
                ("morph_weights", c_float_p), ("source_us", ctypes.c_uint64), ("rotation", ctypes.c_float * 4),
                ("instance", ctypes.c_int32), ("asset", ctypes.c_int32), ("shown", ctypes.c_int32),
                ("bones", ctypes.c_int32), ("bone_count", ctypes.c_int32), ("morph_count", ctypes.c_int32),
                ("published", ctypes.c_int32), ("reserved", ctypes.c_int32)]


class _Asset(ctypes.Structure):
    _fields_ = [("name", ctypes.c_char_p), ("path", ctypes.c_char_p), ("order", ctypes.POINTER(ctypes.c_int32)),
                ("parents", ctypes.POINTER(ctypes.c_int16)), ("inverse_binds", c_float_p), ("positions", c_float_p),
                ("normals", c_float_p), ("triangles", ctypes.POINTER(ctypes.c_uint32)),
                ("joints", ctypes.POINTER(ctypes.c_uint16)), ("weights", c_float_p), ("id", ctypes.c_uint64),
                ("diagonal", ctypes.c_double), ("bone_count", ctypes.c_int32), ("joint_count", ctypes.c_int32),
                ("vertex_count", ctypes.c_int32), ("triangle_count", ctypes.c_int32), ("influences", ctypes.c_int32),
                ("morph_count", ctypes.c_int32), ("clip_count", ctypes.c_int32), ("ready", ctypes.c_int32)]


class _SpawnSpec(ctypes.Structure):
    _fields_ = [("walk_center", ctypes.c_double * 3), ("walk_radius", ctypes.c_double),
                ("walk_speed", ctypes.c_double), ("clips", ctypes.POINTER(ctypes.c_int32)),
                ("start_us", ctypes.c_uint64), ("position", ctypes.c_float * 3), ("speed", ctypes.c_float),
                ("clip_count", ctypes.c_int32), ("asset", ctypes.c_int32), ("once", ctypes.c_int32),
                ("reserved", ctypes.c_int32)]


class _Root(ctypes.Structure):
    _fields_ = [("position", ctypes.c_double * 3), ("source_us", ctypes.c_uint64), ("rotation", ctypes.c_float * 4)]


class _View(ctypes.Structure):
    _fields_ = [("weight_instances", ctypes.POINTER(ctypes.c_int32)), ("weights", c_float_p),
                ("camera", ctypes.c_float * 3), ("fov_y", ctypes.c_float), ("viewport_height", ctypes.c_float),
                ("has_camera", ctypes.c_int32), ("weight_count", ctypes.c_int32), ("reserved", ctypes.c_int32)]


class _Stats(ctypes.Structure):
    _fields_ = [("seconds", ctypes.c_double), ("loss", ctypes.c_double), ("rtt_ms", ctypes.c_double),
                ("estimate_kbps", ctypes.c_double), ("delay_ms", ctypes.c_double),
                ("download_seconds", ctypes.c_double), ("datagrams", ctypes.c_uint64),
                ("wire_bytes", ctypes.c_uint64), ("asset_bytes_downloaded", ctypes.c_uint64),
                ("poses_sent", ctypes.c_uint64), ("poses_refused", ctypes.c_uint64),
                ("assets_cached", ctypes.c_int32), ("reserved", ctypes.c_int32)]


_P = ctypes.c_void_p
_I = ctypes.c_int
_PI = ctypes.POINTER(ctypes.c_int)
_SIGNATURES = {
    "psk_version": (ctypes.c_char_p, []),
    "psk_version_number": (ctypes.c_uint32, []),
    "psk_now": (ctypes.c_double, []),
    "psk_last_error": (ctypes.c_char_p, []),
    "psk_status_name": (ctypes.c_char_p, [_I]),
    "psk_client_config_init": (_I, [ctypes.POINTER(_Config)]),
    "psk_client_create": (_P, [ctypes.POINTER(_Config)]),
    "psk_client_destroy": (_I, [_P]),
    "psk_client_connect": (_I, [_P, ctypes.c_char_p, ctypes.c_uint16]),
    "psk_client_connect_list": (_I, [_P, ctypes.c_char_p]),
    "psk_client_update": (_I, [_P, ctypes.c_double]),
    "psk_client_close": (_I, [_P, ctypes.c_char_p]),
    "psk_client_state": (_I, [_P, _PI]),
    "psk_client_fail_reason": (_I, [_P, _PI]),
    "psk_client_poll_event": (_I, [_P, ctypes.POINTER(_Event)]),
    "psk_client_character_count": (_I, [_P, _PI]),
    "psk_client_character": (_I, [_P, _I, ctypes.POINTER(_Character)]),
    "psk_client_find_character": (_I, [_P, _I, ctypes.POINTER(_Character)]),
    "psk_client_character_world_id": (_I, [_P, _I, ctypes.POINTER(ctypes.c_uint64)]),
    "psk_client_asset_count": (_I, [_P, _PI]),
    "psk_client_asset": (_I, [_P, _I, ctypes.POINTER(_Asset)]),
    "psk_client_sample_clip": (_I, [_P, _I, _I, ctypes.c_double, c_float_p, _I]),
    "psk_spawn_spec_init": (_I, [ctypes.POINTER(_SpawnSpec)]),
    "psk_client_spawn": (_I, [_P, ctypes.POINTER(_SpawnSpec), _PI]),
    "psk_client_instance_of": (_I, [_P, _I, _PI]),
    "psk_client_publish": (_I, [_P, _I, ctypes.POINTER(_Root), c_float_p, _I, c_float_p, _I, _I]),
    "psk_client_despawn": (_I, [_P, _I]),
    "psk_client_set_view": (_I, [_P, ctypes.POINTER(_View)]),
    "psk_client_set_max_kbps": (_I, [_P, ctypes.c_double]),
    "psk_client_stats": (_I, [_P, ctypes.POINTER(_Stats)]),
}
_LIB = None


def load_library(path=None):
    """Loads libprogskin_c.so (path, else $PROGSKIN_C_LIBRARY, else the system's search) once."""
    global _LIB
    if _LIB is not None:
        return _LIB
    path = path or os.environ.get("PROGSKIN_C_LIBRARY") or ctypes.util.find_library("progskin_c")
    if not path:
        raise OSError("progskin: libprogskin_c.so not found: set PROGSKIN_C_LIBRARY to its path, or install "
                      "progskin where the system finds libraries")
    lib = ctypes.CDLL(path)
    for name, (res, args) in _SIGNATURES.items():
        f = getattr(lib, name)
        f.restype, f.argtypes = res, args
    _LIB = lib
    return lib


def _lib():
    return load_library()


def _check(status, allow=(OK,)):
    if status in allow:
        return status
    raise Error(status, _lib().psk_last_error().decode(errors="replace"))


def _b(s):
    return s.encode() if isinstance(s, str) else s


def now():
    """Monotonic seconds: the clock of Client.update."""
    return _lib().psk_now()


def version():
    return _lib().psk_version().decode()


class Event:
    def __init__(self, e):
        self.type, self.instance, self.asset, self.handle = e.type, e.instance, e.asset, e.handle
        self.text = e.text.decode(errors="replace") if e.text else ""

    def __repr__(self):
        return "Event(%s, instance=%d, asset=%d, handle=%d, text=%r)" % (
            EventType.NAMES.get(self.type, self.type), self.instance, self.asset, self.handle, self.text)


class Character:
    """A remote character at the display time. palette: bone_count * 12 floats (3x4 row-major per
    bone, progressive order), a view valid until the next update; morph_weights likewise."""

    def __init__(self, c):
        self.instance, self.asset, self.shown, self.bones = c.instance, c.asset, bool(c.shown), c.bones
        self.bone_count, self.published = c.bone_count, bool(c.published)
        self.position = tuple(c.position)
        self.rotation = tuple(c.rotation)  # x y z w
        self.source_us, self.display_tick = c.source_us, c.display_tick
        n = c.bone_count * 12
        self.palette = ctypes.cast(c.palette, ctypes.POINTER(ctypes.c_float * n)).contents if c.palette else None
        m = c.morph_count
        self.morph_weights = (ctypes.cast(c.morph_weights, ctypes.POINTER(ctypes.c_float * m)).contents
                              if c.morph_weights else None)


class Asset:
    """An asset of the catalogue: what an engine needs to set up its skinned mesh (copied into lists)."""

    def __init__(self, a):
        self.name = a.name.decode()
        self.ready = bool(a.ready)
        self.path = a.path.decode() if a.path else None
        self.bone_count, self.joint_count, self.vertex_count = a.bone_count, a.joint_count, a.vertex_count
        self.influences, self.morph_count, self.clip_count = a.influences, a.morph_count, a.clip_count
        self.triangle_count, self.id, self.diagonal = a.triangle_count, a.id, a.diagonal
        if not self.ready:
            return
        self.order = a.order[:a.bone_count]
        self.parents = a.parents[:a.bone_count]
        self.inverse_binds = a.inverse_binds[:a.bone_count * 12]
        self.joints = a.joints[:a.vertex_count * a.influences] if a.joints else []
        self.weights = a.weights[:a.vertex_count * a.influences] if a.weights else []


class Client:
    """One connection to a progskin-server. Keyword arguments are the C config's fields
    (pin_sha256, ca_file, token, cache_dir, tls, insecure, max_kbps, delay_ms, ...)."""

    def __init__(self, **config):
        lib = _lib()
        cfg = _Config()
        _check(lib.psk_client_config_init(ctypes.byref(cfg)))
        for k, v in config.items():
            if not hasattr(cfg, k):
                raise TypeError("progskin.Client: no config field %r" % k)
            setattr(cfg, k, _b(v) if isinstance(v, str) else v)
        self._h = lib.psk_client_create(ctypes.byref(cfg))
        if not self._h:
            raise Error(-2, lib.psk_last_error().decode(errors="replace"))
        self._ev, self._ch = _Event(), _Character()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.destroy()

    def __del__(self):
        self.destroy()

    def destroy(self):
        """Closes and frees the client (also on garbage collection)."""
        if getattr(self, "_h", None) and _LIB is not None:
            _LIB.psk_client_destroy(self._h)
        self._h = None

    def connect(self, host, port):
        """port: 1-65535 (ValueError otherwise; ctypes would wrap it to 16 bits)."""
        if isinstance(port, bool) or not isinstance(port, int) or not 0 < port < 65536:
            raise ValueError(f"port must be a whole number in 1..65535 (got {port!r})")
        _check(_lib().psk_client_connect(self._h, _b(host), port))

    def connect_list(self, servers):
        """servers: "HOST:PORT[,HOST:PORT...]"; fails over to the next when one is lost."""
        _check(_lib().psk_client_connect_list(self._h, _b(servers)))

    def update(self, t=None):
        """One frame (t: now() by default). Raises Error once the client is Failed."""
        _check(_lib().psk_client_update(self._h, now() if t is None else t))

    def close(self, reason="done"):
        _check(_lib().psk_client_close(self._h, _b(reason)))

    def _int(self, fn, *args):
        v = ctypes.c_int()
        _check(fn(self._h, *args, ctypes.byref(v)))
        return v.value

    def state(self):
        return self._int(_lib().psk_client_state)

    def fail_reason(self):
        return self._int(_lib().psk_client_fail_reason)

    def events(self):
        """The events of the last update."""
        out = []
        while _check(_lib().psk_client_poll_event(self._h, ctypes.byref(self._ev)), (OK, EMPTY)) == OK:
            out.append(Event(self._ev))
        return out

    def character_count(self):
        return self._int(_lib().psk_client_character_count)

    def character(self, index):
        _check(_lib().psk_client_character(self._h, index, ctypes.byref(self._ch)))
        return Character(self._ch)

    def characters(self):
        return [self.character(i) for i in range(self.character_count())]

    def world_id(self, instance):
        """The character's id across a world of servers (0 from a server that sends none)."""
        v = ctypes.c_uint64()
        _check(_lib().psk_client_character_world_id(self._h, instance, ctypes.byref(v)))
        return v.value

    def asset_count(self):
        return self._int(_lib().psk_client_asset_count)

    def asset(self, index):
        """The asset (ready False until downloaded)."""
        a = _Asset()
        _check(_lib().psk_client_asset(self._h, index, ctypes.byref(a)), (OK, NOT_READY))
        return Asset(a)

    def sample_clip(self, asset, clip, t, out=None):
        """Skinning matrices (joint_count * 12 floats) of the asset's clip (-1: all) t s after its start."""
        if out is None:
            out = (ctypes.c_float * (self.asset(asset).joint_count * 12))()
        _check(_lib().psk_client_sample_clip(self._h, asset, clip, t, out, len(out)))
        return out

    def spawn(self, asset=0, clips=(), once=False, speed=1.0, start_us=0, position=(0, 0, 0),
              walk_center=(0, 0, 0), walk_radius=0.0, walk_speed=0.0):
        """Asks the server for a character; returns its handle (a SPAWNED event follows)."""
        s = _SpawnSpec()
        _check(_lib().psk_spawn_spec_init(ctypes.byref(s)))
        s.asset, s.once, s.speed, s.start_us = asset, int(once), speed, start_us
        s.position[:], s.walk_center[:] = list(position), list(walk_center)
        s.walk_radius, s.walk_speed = walk_radius, walk_speed
        arr = (ctypes.c_int32 * len(clips))(*clips)
        s.clips, s.clip_count = ctypes.cast(arr, ctypes.POINTER(ctypes.c_int32)), len(clips)
        return self._int(_lib().psk_client_spawn, ctypes.byref(s))

    def instance_of(self, handle):
        return self._int(_lib().psk_client_instance_of, handle)

    def publish(self, handle, skinning, position=(0, 0, 0), rotation=(0, 0, 0, 1), source_us=None,
                morph_weights=None, teleport=False):
        """Sends a pose: skinning, joint_count * 12 floats (a ctypes float array, e.g. sample_clip's, or a
        sequence). True: sent; False: not spawned yet or the stream not bound."""
        if not isinstance(skinning, ctypes.Array):
            skinning = (ctypes.c_float * len(skinning))(*skinning)
        r = _Root()
        r.position[:], r.rotation[:] = list(position), list(rotation)
        r.source_us = int(now() * 1e6) if source_us is None else source_us
        mw, mc = None, 0
        if morph_weights is not None:
            mw, mc = (ctypes.c_float * len(morph_weights))(*morph_weights), len(morph_weights)
        s = _check(_lib().psk_client_publish(self._h, handle, ctypes.byref(r), skinning, len(skinning) // 12,
                                             mw, mc, int(teleport)), (OK, NOT_READY))
        return s == OK

    def despawn(self, handle):
        _check(_lib().psk_client_despawn(self._h, handle))

    def set_view(self, camera=None, fov_y=0.8, viewport_height=1080.0, weights=None):
        """camera: (x, y, z) or None; weights: {instance: weight}."""
        v = _View()
        if camera is not None:
            v.camera[:], v.has_camera = list(camera), 1
        v.fov_y, v.viewport_height = fov_y, viewport_height
        weights = weights or {}
        ids = (ctypes.c_int32 * len(weights))(*weights.keys())
        ws = (ctypes.c_float * len(weights))(*weights.values())
        v.weight_instances, v.weights = ctypes.cast(ids, ctypes.POINTER(ctypes.c_int32)), ctypes.cast(ws, c_float_p)
        v.weight_count = len(weights)
        _check(_lib().psk_client_set_view(self._h, ctypes.byref(v)))

    def set_max_kbps(self, kbps):
        _check(_lib().psk_client_set_max_kbps(self._h, kbps))

    def stats(self):
        s = _Stats()
        _check(_lib().psk_client_stats(self._h, ctypes.byref(s)))
        return {k: getattr(s, k) for k, _ in _Stats._fields_ if k != "reserved"}
