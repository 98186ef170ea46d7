// Progskin.cs — C# binding of the progskin streaming client: P/Invoke over
// libprogskin_c.so (capi/progskin.h), the way Unity calls native plugins.
// docs/bindings.md describes the contract. One file, no dependency: copy it
// into a project (Unity: Assets/Plugins, beside libprogskin_c.so) or
// compile it with the program (mcs Progskin.cs Game.cs).
//
//   using (var c = new Progskin.Client(new Progskin.Config { PinSha256 = "AB:CD:..." })) {
//       c.Connect("127.0.0.1", 7777);
//       for (;;) {
//           c.Update();                                   // once per frame
//           foreach (var e in c.Events()) ...
//           for (int i = 0; i < c.CharacterCount; ++i) {
//               var ch = c.Character(i);                  // ch.CopyPalette(buffer): 12 floats per bone
//           }
//       }
//   }
//
// Errors throw Progskin.ProgskinException (Status, the library's message).
// A Client is used from one thread at a time (Unity: the main thread).
// Character.Palette points into the library's memory, valid until the next
// Update(); CopyPalette copies it.
using System;
using System.Collections.Generic;
using System.Runtime.InteropServices;

namespace Progskin {

public enum Status { Ok = 0, Empty = 1, NotReady = 2, ErrNull = -1, ErrArgument = -2, ErrState = -3,
                     ErrConnect = -4, ErrFailed = -5, ErrMemory = -6, ErrInternal = -7 }
public enum State { Idle = 0, Connecting = 1, Streaming = 2, Closed = 3, Failed = 4 }
public enum EventType { Connected = 1, AssetReady = 2, CharacterAdded = 3, CharacterRemoved = 4, Spawned = 5,
                        SpawnRefused = 6, Closed = 7, Failed = 8, AssetFailed = 9, FailedOver = 10 }

public class ProgskinException : Exception {
    public readonly Status Status;
    public ProgskinException(Status status, string message) : base(status + ": " + message) { Status = status; }
}

// The C structs, field for field (capi/progskin.h).
[StructLayout(LayoutKind.Sequential)]
public struct NativeConfig {
    public IntPtr name, token, cache_dir, ca_file, pin_sha256, udp_via_host;
    public double max_kbps, delay_ms, max_delay_ms, connect_timeout, stream_timeout;
    public int tls, insecure, blend_frames, snap_to_ticks, udp_via_port, protocol_version;
}

[StructLayout(LayoutKind.Sequential)]
public struct NativeEvent {
    public IntPtr text;
    public int type, instance, asset, handle;
}

[StructLayout(LayoutKind.Sequential)]
public unsafe struct Character {
    public fixed double position[3];
    public double display_tick;
    public IntPtr palette;        // bone_count * 12 floats, valid until the next Update()
    public IntPtr morph_weights;  // morph_count floats or null
    public ulong source_us;
    public fixed float rotation[4];  // x y z w
    public int instance, asset, shown, bones, bone_count, morph_count, published, reserved;

    public bool Shown { get { return shown != 0; } }
    public bool Published { get { return published != 0; } }
    public double X { get { fixed (double* p = position) return p[0]; } }
    public double Y { get { fixed (double* p = position) return p[1]; } }
    public double Z { get { fixed (double* p = position) return p[2]; } }
    // Copies the palette (bone_count * 12 floats, 3x4 row-major per bone, progressive order).
    public void CopyPalette(float[] into) {
        if (palette == IntPtr.Zero) throw new ProgskinException(Status.NotReady, "no palette: the character is not shown");
        if (into.Length < bone_count * 12) throw new ArgumentException("the buffer needs " + bone_count * 12 + " floats");
        Marshal.Copy(palette, into, 0, bone_count * 12);
    }
}

[StructLayout(LayoutKind.Sequential)]
public struct NativeAsset {
    public IntPtr name, path, order, parents, inverse_binds, positions, normals, triangles, joints, weights;
    public ulong id;
    public double diagonal;
    public int bone_count, joint_count, vertex_count, triangle_count, influences, morph_count, clip_count, ready;
}

[StructLayout(LayoutKind.Sequential)]
public unsafe struct SpawnSpec {
    public fixed double walk_center[3];
    public double walk_radius, walk_speed;
    public IntPtr clips;
    public ulong start_us;
    public fixed float position[3];
    public float speed;
    public int clip_count, asset, once, reserved;
}

[StructLayout(LayoutKind.Sequential)]
public unsafe struct Root {
    public fixed double position[3];
    public ulong source_us;
    public fixed float rotation[4];  // x y z w
}

[StructLayout(LayoutKind.Sequential)]
public unsafe struct NativeView {
    public IntPtr weight_instances, weights;
    public fixed float camera[3];
    public float fov_y, viewport_height;
    public int has_camera, weight_count, reserved;
}

[StructLayout(LayoutKind.Sequential)]
public struct Stats {
    public double seconds, loss, rtt_ms, estimate_kbps, delay_ms, download_seconds;
    public ulong datagrams, wire_bytes, asset_bytes_downloaded, poses_sent, poses_refused;
    public int assets_cached, reserved;
}

public static class Native {
    public const string Lib = "progskin_c";  // libprogskin_c.so (LD_LIBRARY_PATH, or beside the program)
    [DllImport(Lib)] public static extern IntPtr psk_version();
    [DllImport(Lib)] public static extern uint psk_version_number();
    [DllImport(Lib)] public static extern double psk_now();
    [DllImport(Lib)] public static extern IntPtr psk_last_error();
    [DllImport(Lib)] public static extern Status psk_client_config_init(ref NativeConfig c);
    [DllImport(Lib)] public static extern IntPtr psk_client_create(ref NativeConfig c);
    [DllImport(Lib)] public static extern Status psk_client_destroy(IntPtr c);
    [DllImport(Lib)] public static extern Status psk_client_connect(IntPtr c, [MarshalAs(UnmanagedType.LPUTF8Str)] string host, ushort port);
    [DllImport(Lib)] public static extern Status psk_client_connect_list(IntPtr c, [MarshalAs(UnmanagedType.LPUTF8Str)] string servers);
    [DllImport(Lib)] public static extern Status psk_client_update(IntPtr c, double now);
    [DllImport(Lib)] public static extern Status psk_client_close(IntPtr c, [MarshalAs(UnmanagedType.LPUTF8Str)] string reason);
    [DllImport(Lib)] public static extern Status psk_client_state(IntPtr c, out State s);
    [DllImport(Lib)] public static extern Status psk_client_poll_event(IntPtr c, out NativeEvent e);
    [DllImport(Lib)] public static extern Status psk_client_character_count(IntPtr c, out int n);
    [DllImport(Lib)] public static extern Status psk_client_character(IntPtr c, int index, out Character ch);
    [DllImport(Lib)] public static extern Status psk_client_find_character(IntPtr c, int instance, out Character ch);
    [DllImport(Lib)] public static extern Status psk_client_character_world_id(IntPtr c, int instance, out ulong worldId);
    [DllImport(Lib)] public static extern Status psk_client_asset_count(IntPtr c, out int n);
    [DllImport(Lib)] public static extern Status psk_client_asset(IntPtr c, int index, out NativeAsset a);
    [DllImport(Lib)] public static extern Status psk_client_sample_clip(IntPtr c, int asset, int clip, double t, [Out] float[] o, int capacity);
    [DllImport(Lib)] public static extern Status psk_spawn_spec_init(ref SpawnSpec s);
    [DllImport(Lib)] public static extern Status psk_client_spawn(IntPtr c, ref SpawnSpec s, out int handle);
    [DllImport(Lib)] public static extern Status psk_client_instance_of(IntPtr c, int handle, out int instance);
    [DllImport(Lib)] public static extern Status psk_client_publish(IntPtr c, int handle, ref Root root, float[] skinning, int joints,
                                                                    float[] morphs, int morph_count, int teleport);
    [DllImport(Lib)] public static extern Status psk_client_despawn(IntPtr c, int handle);
    [DllImport(Lib)] public static extern Status psk_client_set_view(IntPtr c, ref NativeView v);
    [DllImport(Lib)] public static extern Status psk_client_set_max_kbps(IntPtr c, double kbps);
    [DllImport(Lib)] public static extern Status psk_client_stats(IntPtr c, out Stats s);

    public static string Str(IntPtr p) { return p == IntPtr.Zero ? null : PtrToUtf8(p); }
    static string PtrToUtf8(IntPtr p) {
        int n = 0;
        while (Marshal.ReadByte(p, n) != 0) ++n;
        var b = new byte[n];
        Marshal.Copy(p, b, 0, n);
        return System.Text.Encoding.UTF8.GetString(b);
    }
    public static Status Check(Status s, params Status[] allowed) {
        if (s == Status.Ok) return s;
        foreach (var a in allowed) if (s == a) return s;
        throw new ProgskinException(s, Str(psk_last_error()));
    }
}

public class Config {
    public string Name, Token, CacheDir, CaFile, PinSha256;
    public bool Tls = true, Insecure = false;
    public double MaxKbps = 0, DelayMs = 100;
}

public struct Event {
    public EventType Type;
    public int Instance, Asset, Handle;
    public string Text;
    public override string ToString() { return Type + " instance " + Instance + " asset " + Asset + " handle " + Handle + " " + Text; }
}

// An asset of the catalogue, copied: what an engine needs to set up its skinned mesh.
public class Asset {
    public string Name, Path;
    public bool Ready;
    public int BoneCount, JointCount, VertexCount, Influences, MorphCount, ClipCount;
    public int[] Order;           // progressive bone -> glTF skin joint
    public short[] Parents;       // progressive parent, -1 for bone 0
    public float[] InverseBinds;  // BoneCount * 12
}

public sealed class Client : IDisposable {
    IntPtr h;

    public Client(Config cfg) {
        var n = new NativeConfig();
        Native.Check(Native.psk_client_config_init(ref n));
        var strings = new List<IntPtr>();
        Func<string, IntPtr> s = v => { if (v == null) return IntPtr.Zero; var p = Utf8(v); strings.Add(p); return p; };
        try {
            n.name = s(cfg.Name); n.token = s(cfg.Token); n.cache_dir = s(cfg.CacheDir);
            n.ca_file = s(cfg.CaFile); n.pin_sha256 = s(cfg.PinSha256);
            n.tls = cfg.Tls ? 1 : 0; n.insecure = cfg.Insecure ? 1 : 0;
            n.max_kbps = cfg.MaxKbps; n.delay_ms = cfg.DelayMs;
            h = Native.psk_client_create(ref n);  // copies the strings
            if (h == IntPtr.Zero) throw new ProgskinException(Status.ErrArgument, Native.Str(Native.psk_last_error()));
        } finally {
            foreach (var p in strings) Marshal.FreeHGlobal(p);
        }
    }

    static IntPtr Utf8(string v) {
        var b = System.Text.Encoding.UTF8.GetBytes(v);
        var p = Marshal.AllocHGlobal(b.Length + 1);
        Marshal.Copy(b, 0, p, b.Length);
        Marshal.WriteByte(p, b.Length, 0);
        return p;
    }

    public static double Now { get { return Native.psk_now(); } }
    public static string Version { get { return Native.Str(Native.psk_version()); } }

    public void Dispose() {
        if (h != IntPtr.Zero) Native.psk_client_destroy(h);
        h = IntPtr.Zero;
        GC.SuppressFinalize(this);
    }
    ~Client() { if (h != IntPtr.Zero) Native.psk_client_destroy(h); }

    IntPtr H { get { if (h == IntPtr.Zero) throw new ObjectDisposedException("Progskin.Client"); return h; } }

    public void Connect(string host, int port) {
        if (port < 1 || port > 65535) throw new ArgumentOutOfRangeException("port");
        Native.Check(Native.psk_client_connect(H, host, (ushort)port));
    }
    // servers: "HOST:PORT[,HOST:PORT...]"; fails over to the next when one is lost.
    public void ConnectList(string servers) { Native.Check(Native.psk_client_connect_list(H, servers)); }
    public void Update() { Update(Now); }
    public void Update(double now) { Native.Check(Native.psk_client_update(H, now)); }
    public void Close(string reason) { Native.Check(Native.psk_client_close(H, reason)); }
    public State State { get { State s; Native.Check(Native.psk_client_state(H, out s)); return s; } }

    public List<Event> Events() {
        var list = new List<Event>();
        NativeEvent e;
        while (Native.Check(Native.psk_client_poll_event(H, out e), Status.Empty) == Status.Ok)
            list.Add(new Event { Type = (EventType)e.type, Instance = e.instance, Asset = e.asset, Handle = e.handle,
                                 Text = Native.Str(e.text) });
        return list;
    }

    public int CharacterCount { get { int n; Native.Check(Native.psk_client_character_count(H, out n)); return n; } }
    public Character Character(int index) {
        Character c;
        Native.Check(Native.psk_client_character(H, index, out c));
        return c;
    }

    // The character's id across a world of servers (0 from a server that sends none).
    public ulong WorldId(int instance) {
        ulong w;
        Native.Check(Native.psk_client_character_world_id(H, instance, out w));
        return w;
    }

    public int AssetCount { get { int n; Native.Check(Native.psk_client_asset_count(H, out n)); return n; } }
    public Asset Asset(int index) {
        NativeAsset a;
        var st = Native.Check(Native.psk_client_asset(H, index, out a), Status.NotReady);
        var r = new Asset { Name = Native.Str(a.name), Ready = st == Status.Ok };
        if (!r.Ready) return r;
        r.Path = Native.Str(a.path);
        r.BoneCount = a.bone_count; r.JointCount = a.joint_count; r.VertexCount = a.vertex_count;
        r.Influences = a.influences; r.MorphCount = a.morph_count; r.ClipCount = a.clip_count;
        r.Order = new int[a.bone_count];
        Marshal.Copy(a.order, r.Order, 0, a.bone_count);
        r.Parents = new short[a.bone_count];
        Marshal.Copy(a.parents, r.Parents, 0, a.bone_count);
        r.InverseBinds = new float[a.bone_count * 12];
        Marshal.Copy(a.inverse_binds, r.InverseBinds, 0, a.bone_count * 12);
        return r;
    }

    // Skinning matrices (JointCount * 12 floats) of the asset's clip (-1: all) t seconds after its start.
    public void SampleClip(int asset, int clip, double t, float[] into) {
        Native.Check(Native.psk_client_sample_clip(H, asset, clip, t, into, into.Length));
    }

    public int Spawn(int asset) { return Spawn(asset, 0, 0, 0, null, 1); }

    // Spawns at (x, y, z), announcing clips (catalogue clip indices, null: none) at the given speed.
    public unsafe int Spawn(int asset, float x, float y, float z, int[] clips, float speed) {
        if (clips != null && clips.Length > 64) throw new ArgumentException("at most 64 clips", "clips");
        var s = new SpawnSpec();
        Native.Check(Native.psk_spawn_spec_init(ref s));
        s.asset = asset;
        s.position[0] = x; s.position[1] = y; s.position[2] = z;
        s.speed = speed;
        int handle;
        fixed (int* c = clips) {
            s.clips = (IntPtr)c;
            s.clip_count = clips == null ? 0 : clips.Length;
            Native.Check(Native.psk_client_spawn(H, ref s, out handle));
        }
        return handle;
    }
    public int InstanceOf(int handle) { int i; Native.Check(Native.psk_client_instance_of(H, handle, out i)); return i; }

    // Sends a pose (skinning: JointCount * 12 floats). True: sent; false: not spawned yet or the stream not bound.
    public bool Publish(int handle, float[] skinning, double x, double y, double z, ulong sourceUs) {
        return Publish(handle, skinning, x, y, z, 0, 0, 0, 1, sourceUs, null, false);
    }

    // The same with the root's rotation (quaternion x y z w), morph weights (null: none) and a teleport
    // (the observers snap instead of interpolating from the previous pose).
    public unsafe bool Publish(int handle, float[] skinning, double x, double y, double z,
                               float qx, float qy, float qz, float qw, ulong sourceUs, float[] morphs, bool teleport) {
        if (skinning == null) throw new ArgumentNullException("skinning");
        if (skinning.Length % 12 != 0) throw new ArgumentException("skinning needs 12 floats per joint", "skinning");
        var r = new Root();
        r.position[0] = x; r.position[1] = y; r.position[2] = z;
        r.rotation[0] = qx; r.rotation[1] = qy; r.rotation[2] = qz; r.rotation[3] = qw;
        r.source_us = sourceUs;
        return Native.Check(Native.psk_client_publish(H, handle, ref r, skinning, skinning.Length / 12, morphs,
                                                      morphs == null ? 0 : morphs.Length, teleport ? 1 : 0),
                            Status.NotReady) == Status.Ok;
    }

    // The viewer's camera (world position, vertical field of view in radians, viewport height in pixels)
    // and optional importance weights per instance (null: none): the server ranks characters by it.
    public unsafe void SetView(float x, float y, float z, float fovY, float viewportHeight,
                               int[] weightInstances, float[] weights) {
        int n = weightInstances == null ? 0 : weightInstances.Length;
        if ((weights == null ? 0 : weights.Length) != n)
            throw new ArgumentException("weightInstances and weights need the same length");
        var v = new NativeView();
        v.camera[0] = x; v.camera[1] = y; v.camera[2] = z;
        v.fov_y = fovY; v.viewport_height = viewportHeight;
        v.has_camera = 1;
        v.weight_count = n;
        fixed (int* wi = weightInstances)
        fixed (float* w = weights) {
            v.weight_instances = (IntPtr)wi;
            v.weights = (IntPtr)w;
            Native.Check(Native.psk_client_set_view(H, ref v));
        }
    }
    public void SetView(float x, float y, float z) { SetView(x, y, z, 0.8f, 1080f, null, null); }
    public void Despawn(int handle) { Native.Check(Native.psk_client_despawn(H, handle)); }
    public void SetMaxKbps(double kbps) { Native.Check(Native.psk_client_set_max_kbps(H, kbps)); }
    public Stats Stats { get { Stats s; Native.Check(Native.psk_client_stats(H, out s)); return s; } }
}

}  // namespace Progskin
