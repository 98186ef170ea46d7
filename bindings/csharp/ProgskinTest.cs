// ProgskinTest.cs — the C# binding against a real progskin-server on
// loopback (run by tests/with_server.py, which sets PROGSKIN_HOST,
// PROGSKIN_PORT, PROGSKIN_PIN, PROGSKIN_INSTANCES, PROGSKIN_CACHE): an
// observer sees every character of the scene within 2 s; a player spawns a
// character and publishes it from its clip, and the observer sees it within
// 2 s of the spawn; bad input throws ProgskinException with a status and a
// reason. Exit 0 when every check holds.
//
//   mcs -unsafe -out:build/progskin_test.exe bindings/csharp/Progskin.cs bindings/csharp/ProgskinTest.cs
//   python3 tests/with_server.py --server build/server/progskin-server -- \
//       env LD_LIBRARY_PATH=build/capi mono build/progskin_test.exe
using System;
using System.Threading;
using Progskin;

static class ProgskinTest {
    static int failures = 0;

    static void Check(bool ok, string what) {
        if (ok) return;
        ++failures;
        Console.Error.WriteLine("FAIL: " + what);
    }

    static string Env(string name) {
        var v = Environment.GetEnvironmentVariable(name);
        if (v == null) {
            Console.Error.WriteLine("ProgskinTest: " + name + " is not set (run it with tests/with_server.py)");
            Environment.Exit(2);
        }
        return v;
    }

    static Client Connect(string name) {
        var c = new Client(new Config { Name = name, PinSha256 = Env("PROGSKIN_PIN"), CacheDir = Env("PROGSKIN_CACHE") });
        c.Connect(Env("PROGSKIN_HOST"), int.Parse(Env("PROGSKIN_PORT")));
        return c;
    }

    // Characters shown, each with a finite palette of every bone; published: a player's (-1: none).
    static int Shown(Client c, out int published) {
        published = -1;
        int shown = 0;
        var buf = new float[0];
        for (int i = 0; i < c.CharacterCount; ++i) {
            var ch = c.Character(i);
            if (!ch.Shown) continue;
            Check(ch.bone_count > 0 && ch.bones >= 1 && ch.bones <= ch.bone_count, "character " + ch.instance + " bones");
            if (buf.Length < ch.bone_count * 12) buf = new float[ch.bone_count * 12];
            ch.CopyPalette(buf);
            for (int k = 0; k < ch.bone_count * 12; ++k)
                if (float.IsNaN(buf[k]) || float.IsInfinity(buf[k])) { Check(false, "palette not finite"); break; }
            Check(c.WorldId(ch.instance) != 0, "character " + ch.instance + " world id");
            if (ch.Published) published = ch.instance;
            ++shown;
        }
        return shown;
    }

    static void Step(Client c, double now) {
        c.Update(now);
        foreach (var e in c.Events())
            Check(e.Type != EventType.Failed && e.Type != EventType.SpawnRefused, "event " + e);
    }

    static void Throws(Status expected, Action a, string what) {
        try {
            a();
            Check(false, what + ": no exception");
        } catch (ProgskinException e) {
            Check(e.Status == expected && e.Message.Length > 0, what + ": " + e.Message);
        }
    }

    static void BadInput(Client c) {
        Throws(Status.ErrArgument, () => c.Character(-1), "Character(-1)");
        Throws(Status.ErrArgument, () => c.Asset(99), "Asset(99)");
        Throws(Status.ErrState, () => c.Connect("127.0.0.1", 1), "Connect twice");
        Throws(Status.ErrArgument, () => c.SetMaxKbps(double.NaN), "SetMaxKbps(NaN)");
        Throws(Status.ErrArgument, () => c.Publish(12345, new float[12], 0, 0, 0, 0), "Publish(unknown handle)");
        Throws(Status.ErrArgument, () => c.SetView(0, 1, 0, 4f, 1080f, null, null), "SetView(fov 4 rad)");
        try {
            c.Publish(12345, null, 0, 0, 0, 0);
            Check(false, "Publish(null skinning) did not throw");
        } catch (ArgumentNullException) {
        }
        c.SetView(0, 1.6f, 5, 0.8f, 1080f, new int[] { 0 }, new float[] { 2f });  // a camera and one weighted instance
        c.SetView(0, 1.6f, 5);
        Check(c.State == State.Streaming, "state " + c.State);
    }

    static int Main() {
        int instances = int.Parse(Env("PROGSKIN_INSTANCES"));
        Console.WriteLine("progskin C library " + Client.Version);
        int published;
        using (var observer = Connect("cs-observer")) {
            double t0 = Client.Now, seen = -1;
            while (Client.Now - t0 < 5 && seen < 0) {
                Step(observer, Client.Now);
                if (Shown(observer, out published) == instances) seen = Client.Now - t0;
                Thread.Sleep(10);
            }
            Check(seen >= 0 && seen <= 2.0, "saw all " + instances + " characters after " + seen + " s");
            Console.WriteLine("observer: all {0} characters shown {1:F3} s after connect", instances, seen);
            BadInput(observer);

            using (var player = Connect("cs-player")) {
                int handle = -1, instance = -1;
                double spawnedAt = -1, seenPublished = -1;
                float[] skin = null;
                t0 = Client.Now;
                while (Client.Now - t0 < 8 && seenPublished < 0) {
                    double now = Client.Now;
                    Step(player, now);
                    Step(observer, now);
                    if (handle < 0 && player.AssetCount > 0) {
                        var a = player.Asset(0);
                        if (a.Ready) {
                            Check(a.Order.Length == a.BoneCount && a.Parents[0] == -1 && System.IO.File.Exists(a.Path),
                                  "asset 0: " + a.Name + " at " + a.Path);
                            skin = new float[a.JointCount * 12];
                            handle = player.Spawn(0, 3, 0, 0, null, 1);
                            spawnedAt = now;
                        }
                    }
                    if (handle >= 0 && instance < 0) instance = player.InstanceOf(handle);
                    if (instance >= 0) {
                        player.SampleClip(0, -1, now - spawnedAt, skin);
                        // the root turns with the walk around the circle (rotation about y)
                        float half = (float)(-now / 2);
                        player.Publish(handle, skin, 3 * Math.Cos(now), 0, 3 * Math.Sin(now), 0, (float)Math.Sin(half), 0,
                                       (float)Math.Cos(half), (ulong)(now * 1e6), null, false);
                    }
                    Shown(observer, out published);
                    if (published >= 0 && published == instance) seenPublished = now - spawnedAt;
                    Thread.Sleep(10);
                }
                Check(instance >= 0, "the spawn was confirmed");
                Check(seenPublished >= 0 && seenPublished <= 2.0, "observer saw the published character after " + seenPublished + " s");
                Check(Shown(observer, out published) == instances + 1, "observer shows the scene and the player");
                // The observer can show the player's character before the
                // player shows the whole scene (it joined a moment ago): within 2 s more.
                double t1 = Client.Now;
                int playerShows = Shown(player, out published);
                while (playerShows < instances && Client.Now - t1 < 2.0) {
                    Step(player, Client.Now);
                    Step(observer, Client.Now);
                    playerShows = Shown(player, out published);
                    Thread.Sleep(10);
                }
                Check(playerShows == instances && published < 0,
                      "the player sees the scene (" + playerShows + " of " + instances + "), not itself");
                Check(player.Stats.poses_sent > 0, "poses sent");
                Console.WriteLine("observer: the player's character {0} shown {1:F3} s after its spawn", instance, seenPublished);
                player.Despawn(handle);
                player.Close("bye");
            }
            observer.Close("done");
        }
        if (failures > 0) Console.Error.WriteLine("ProgskinTest: " + failures + " check(s) failed");
        else Console.WriteLine("ProgskinTest: every check passed");
        return failures > 0 ? 1 : 0;
    }
}
