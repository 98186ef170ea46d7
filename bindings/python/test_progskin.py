#!/usr/bin/env python3
"""The Python binding against a real progskin-server on loopback (run by
tests/with_server.py, which sets PROGSKIN_HOST, PROGSKIN_PORT, PROGSKIN_PIN,
PROGSKIN_INSTANCES, PROGSKIN_CACHE; ctest passes PROGSKIN_C_LIBRARY):
an observer sees every character of the scene within 2 s; a player spawns
a character and publishes it from its clip, and the observer sees it within
2 s of the spawn; bad input raises progskin.Error with a status and a reason.

    python3 tests/with_server.py --server build/server/progskin-server -- \\
        env PROGSKIN_C_LIBRARY=build/capi/libprogskin_c.so python3 bindings/python/test_progskin.py
"""
import math
import os
import sys
import time
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import progskin  # noqa: E402


def env(name):
    if name not in os.environ:
        raise unittest.SkipTest("%s is not set: run this test with tests/with_server.py" % name)
    return os.environ[name]


def client(name):
    c = progskin.Client(name=name, pin_sha256=env("PROGSKIN_PIN"), cache_dir=env("PROGSKIN_CACHE"))
    c.connect(env("PROGSKIN_HOST"), int(env("PROGSKIN_PORT")))
    return c


def shown(c):
    """The characters shown, each checked: a finite palette of every bone."""
    out = []
    for ch in c.characters():
        if not ch.shown:
            continue
        assert ch.palette is not None and len(ch.palette) == ch.bone_count * 12, ch.instance
        assert 1 <= ch.bones <= ch.bone_count
        assert all(math.isfinite(v) for v in ch.palette)
        assert c.world_id(ch.instance) != 0, ch.instance
        out.append(ch)
    return out


class Loopback(unittest.TestCase):
    def test_scene_and_publish(self):
        instances = int(env("PROGSKIN_INSTANCES"))
        print("progskin C library", progskin.version())
        with client("py-observer") as observer:
            t0 = progskin.now()
            seen = None
            while progskin.now() - t0 < 5 and seen is None:
                observer.update()
                for e in observer.events():
                    self.assertNotIn(e.type, (progskin.EventType.FAILED, progskin.EventType.SPAWN_REFUSED), e)
                if len(shown(observer)) == instances:
                    seen = progskin.now() - t0
                time.sleep(0.01)
            self.assertIsNotNone(seen, "the observer never showed all %d characters" % instances)
            self.assertLessEqual(seen, 2.0)
            print("observer: all %d characters shown %.3f s after connect" % (instances, seen))
            self.check_bad_input(observer)

            with client("py-player") as player:
                handle, instance, spawned_at, seen_published, skin = None, -1, None, None, None
                t0 = progskin.now()
                while progskin.now() - t0 < 8 and seen_published is None:
                    now = progskin.now()
                    player.update(now)
                    observer.update(now)
                    for e in player.events() + observer.events():
                        self.assertNotIn(e.type, (progskin.EventType.FAILED, progskin.EventType.SPAWN_REFUSED), e)
                    if handle is None and player.asset_count() > 0:
                        a = player.asset(0)
                        if a.ready:
                            self.assertEqual(len(a.order), a.bone_count)
                            self.assertEqual(a.parents[0], -1)
                            self.assertEqual(len(a.inverse_binds), a.bone_count * 12)
                            self.assertTrue(os.path.isfile(a.path), a.path)
                            handle, spawned_at = player.spawn(asset=0), now
                    if handle is not None and instance < 0:
                        instance = player.instance_of(handle)
                    if instance >= 0:
                        skin = player.sample_clip(0, -1, now - spawned_at, skin)
                        player.publish(handle, skin, position=(3 * math.cos(now), 0, 3 * math.sin(now)))
                    if any(ch.published and ch.instance == instance for ch in shown(observer)):
                        seen_published = now - spawned_at
                    time.sleep(0.01)
                self.assertGreaterEqual(instance, 0, "the spawn was never confirmed")
                self.assertIsNotNone(seen_published, "the observer never showed the published character")
                self.assertLessEqual(seen_published, 2.0)
                self.assertEqual(len(shown(observer)), instances + 1)
                self.assertFalse(any(ch.instance == instance for ch in player.characters()), "the player sees itself")
                print("observer: the player's character %d shown %.3f s after its spawn" % (instance, seen_published))
                self.assertGreater(player.stats()["poses_sent"], 0)
                player.despawn(handle)
                player.close("bye")
            observer.close()

    def check_bad_input(self, c):
        with self.assertRaises(progskin.Error) as e:
            c.character(-1)
        self.assertIn("index -1", e.exception.message)
        with self.assertRaises(progskin.Error) as e:
            c.asset(99)
        self.assertEqual(e.exception.status, -2)
        with self.assertRaises(progskin.Error):
            c.set_max_kbps(float("nan"))
        with self.assertRaises(progskin.Error) as e:
            c.connect("127.0.0.1", 1)
        self.assertEqual(e.exception.status, -3)
        for port in (0, 65536, 17777 + 65536, -1):  # never wrapped to 16 bits
            with self.assertRaises(ValueError):
                c.connect("127.0.0.1", port)
        with self.assertRaises(progskin.Error):
            c.publish(12345, [0.0] * 12)
        with self.assertRaises(TypeError):
            progskin.Client(no_such_field=1)
        self.assertEqual(c.state(), progskin.State.STREAMING)


if __name__ == "__main__":
    unittest.main(verbosity=2)
