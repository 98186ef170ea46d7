/* progskin.h — the C API of the progskin streaming client (C99), in the
 * shared library libprogskin_c.so (CMake: find_package(progskin), target
 * progskin::c). The C# (P/Invoke) and Python (ctypes) bindings load the
 * same library. docs/bindings.md is the contract in full; in short:
 *
 *   psk_client_config cfg;
 *   psk_client_config_init(&cfg);          // TLS on: set pin_sha256 or ca_file
 *   cfg.pin_sha256 = "AB:CD:...";          // progskin-server prints it
 *   psk_client* c = psk_client_create(&cfg);   // NULL: psk_last_error() says why
 *   psk_client_connect(c, "127.0.0.1", 7777);
 *   for (;;) {                             // the game's loop, one thread
 *       psk_client_update(c, psk_now());
 *       psk_event e;
 *       while (psk_client_poll_event(c, &e) == PSK_OK) ...
 *       int n = 0;
 *       psk_client_character_count(c, &n);
 *       for (int i = 0; i < n; ++i) {
 *           psk_character ch;
 *           psk_client_character(c, i, &ch);  // ch.palette: 12 floats per bone
 *       }
 *   }
 *   psk_client_close(c, "bye");
 *   psk_client_destroy(c);
 *
 * Statuses: every function returns a psk_status (PSK_OK is 0; errors are
 * negative; PSK_EMPTY and PSK_NOT_READY are positive answers, not errors),
 * except psk_client_create (the handle, or NULL), psk_now, psk_last_error,
 * psk_status_name, psk_version and psk_version_number, which cannot fail.
 * psk_last_error() is the message of the last call on the calling thread
 * (empty after a call that returned PSK_OK); it is thread-local.
 *
 * Threads: the library starts no thread and calls no callback. A client may
 * be used from any thread, one at a time (no two calls on the same client
 * at once); different clients are independent.
 *
 * Lifetimes: strings passed in are copied. What the library returns is
 * owned by it: event texts, character palettes and morph weights are valid
 * until the next psk_client_update, psk_client_close or psk_client_destroy
 * of that client; asset data (psk_asset) is valid until psk_client_destroy.
 *
 * Matrices are 3x4, row-major, 12 floats (the bottom row 0 0 0 1 is left out):
 * m[row * 4 + column]. Palettes are in progressive bone order (psk_asset).
 */
#ifndef PROGSKIN_PROGSKIN_H
#define PROGSKIN_PROGSKIN_H

#include <stddef.h>
#include <stdint.h>

#if defined(_WIN32) && defined(PSK_BUILDING)
#define PSK_API __declspec(dllexport)
#elif defined(_WIN32)
#define PSK_API __declspec(dllimport)
#elif defined(__GNUC__)
#define PSK_API __attribute__((visibility("default")))
#else
#define PSK_API
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* The version of this header; psk_version_number() is the library's. A
 * library of the same major and minor version is ABI-compatible. */
#define PSK_VERSION_MAJOR 0
#define PSK_VERSION_MINOR 1
#define PSK_VERSION_PATCH 0
#define PSK_VERSION_NUMBER ((PSK_VERSION_MAJOR << 16) | (PSK_VERSION_MINOR << 8) | PSK_VERSION_PATCH)

typedef enum psk_status {
    PSK_OK = 0,
    PSK_EMPTY = 1,            /* psk_client_poll_event: no event left (not an error) */
    PSK_NOT_READY = 2,        /* not yet: an asset not downloaded, a spawn not confirmed, the stream not bound */
    PSK_ERR_NULL = -1,        /* a required pointer is NULL */
    PSK_ERR_ARGUMENT = -2,    /* a value out of range: an index, a count, a port, a non-finite number */
    PSK_ERR_STATE = -3,       /* not in this state (connect twice, publish before connect, ...) */
    PSK_ERR_CONNECT = -4,     /* the host cannot be resolved */
    PSK_ERR_FAILED = -5,      /* the client is Failed: psk_last_error() and psk_client_fail_reason() say why */
    PSK_ERR_MEMORY = -6,      /* out of memory */
    PSK_ERR_INTERNAL = -7     /* an unexpected error inside the library (the message says which) */
} psk_status;

typedef enum psk_state {
    PSK_STATE_IDLE = 0,        /* before psk_client_connect */
    PSK_STATE_CONNECTING = 1,  /* TCP, TLS, Hello, Welcome, asset downloads, UDP bind */
    PSK_STATE_STREAMING = 2,   /* frames arrive, characters are displayed */
    PSK_STATE_CLOSED = 3,      /* psk_client_close (the server's Goodbye is FAILED, reason SESSION_ENDED) */
    PSK_STATE_FAILED = 4       /* see psk_client_fail_reason and psk_last_error */
} psk_state;

typedef enum psk_fail_reason {
    PSK_FAIL_NONE = 0,
    PSK_FAIL_CONFIG = 1,           /* TLS with nothing to trust the certificate by, a bad pin, an unreadable CA file */
    PSK_FAIL_UNREACHABLE = 2,
    PSK_FAIL_TLS_HANDSHAKE = 3,
    PSK_FAIL_TLS_UNTRUSTED = 4,    /* the certificate is not trusted (CA chain, host name, pin) */
    PSK_FAIL_TIMEOUT = 5,
    PSK_FAIL_REFUSED = 6,          /* the server's Refuse (version, token, full) */
    PSK_FAIL_BAD_SERVER_DATA = 7,
    PSK_FAIL_CHANNEL_LOST = 8,
    PSK_FAIL_SESSION_ENDED = 9,    /* the server's Goodbye */
    PSK_FAIL_STREAM_LOST = 10,
    PSK_FAIL_LOCAL_IO = 11         /* the asset cache cannot be written */
} psk_fail_reason;

typedef enum psk_event_type {
    PSK_EVENT_CONNECTED = 1,          /* Welcome received */
    PSK_EVENT_ASSET_READY = 2,        /* asset: downloaded (or found in the cache) and loaded */
    PSK_EVENT_CHARACTER_ADDED = 3,    /* instance */
    PSK_EVENT_CHARACTER_REMOVED = 4,  /* instance */
    PSK_EVENT_SPAWNED = 5,            /* handle (psk_client_spawn) now owns instance */
    PSK_EVENT_SPAWN_REFUSED = 6,      /* handle; text: the server's reason */
    PSK_EVENT_CLOSED = 7,             /* text: why */
    PSK_EVENT_FAILED = 8,             /* text: why */
    PSK_EVENT_ASSET_FAILED = 9,       /* asset cannot be loaded; text: why. The session goes on without its characters */
    PSK_EVENT_FAILED_OVER = 10        /* the server was lost (text: why, and the next server of
                                         psk_client_connect_list): remote characters are removed, the
                                         player's spawned again there (PSK_EVENT_SPAWNED, new instance) */
} psk_event_type;

typedef struct psk_client psk_client; /* opaque */

/* Fill with psk_client_config_init, then change fields. Strings may be NULL
 * (the default) and are copied by psk_client_create. */
typedef struct psk_client_config {
    const char* name;          /* sent in Hello (default "progskin-client") */
    const char* token;         /* access token (server --token or a signed connect token) */
    const char* cache_dir;     /* asset cache (default $XDG_CACHE_HOME/progskin or ~/.cache/progskin) */
    const char* ca_file;       /* TLS: trust certificates signed by a CA of this PEM file (host name checked) */
    const char* pin_sha256;    /* TLS: trust the certificate with this SHA-256 (hex, colons allowed) */
    const char* udp_via_host;  /* send UDP here instead (progskin-netem); NULL: the server */
    double max_kbps;           /* rate cap asked of the server; 0: the server's maximum */
    double delay_ms;           /* display delay behind the newest frame, minimum (default 100) */
    double max_delay_ms;       /* the delay adapts up to this (default 600) */
    double connect_timeout;    /* seconds from connect until streaming (default 10) */
    double stream_timeout;     /* seconds without datagrams while characters exist: lost (default 5) */
    int32_t tls;               /* TLS on the control channel (default 1; 0 for a server run with --no-tls) */
    int32_t insecure;          /* TLS: accept any certificate (development only; default 0) */
    int32_t blend_frames;      /* frames of blending for bones switching on or off (default 8) */
    int32_t snap_to_ticks;     /* display exactly on server ticks (default 0) */
    int32_t udp_via_port;      /* with udp_via_host */
    int32_t protocol_version;  /* 0: the library's (tests send others) */
} psk_client_config;

/* One event of the last update (psk_client_poll_event). */
typedef struct psk_event {
    const char* text;  /* never NULL ("" when none); valid until the next update */
    int32_t type;      /* psk_event_type */
    int32_t instance;  /* -1 when not relevant */
    int32_t asset;
    int32_t handle;
} psk_event;

/* A remote character at the display time (psk_client_character). */
typedef struct psk_character {
    double position[3];         /* world root position */
    double display_tick;        /* the server tick displayed */
    const float* palette;       /* bone_count * 12 floats, progressive order; valid until the next update; NULL, bone_count 0, until shown */
    const float* morph_weights; /* morph_count floats (apply before skinning), NULL when none */
    uint64_t source_us;         /* the displayed pose's producer time */
    float rotation[4];          /* world root rotation, quaternion x y z w */
    int32_t instance;           /* the server's instance id */
    int32_t asset;              /* index into the catalogue (psk_client_asset) */
    int32_t shown;              /* 1: a pose exists at the display time (palette valid) */
    int32_t bones;              /* bones shown (the level of detail); the rest copy their parent's */
    int32_t bone_count;         /* matrices in palette: every bone of the asset once shown, 0 before */
    int32_t morph_count;
    int32_t published;          /* 1: a player publishes it (psk_client_spawn elsewhere) */
    int32_t reserved;
} psk_character;

/* An asset of the server's catalogue: what an engine needs to set up its own
 * skinned mesh. Every pointer is valid until psk_client_destroy. */
typedef struct psk_asset {
    const char* name;             /* catalogue name (e.g. "Fox.glb") */
    const char* path;             /* the cached glTF file (absolute or relative to the working directory) */
    const int32_t* order;         /* bone_count: progressive bone b -> glTF skin joint order[b] */
    const int16_t* parents;       /* bone_count: progressive parent (parents[0] = -1, parents[b] < b) */
    const float* inverse_binds;   /* bone_count * 12: inverse bind matrix of bone b (joint order[b]) */
    const float* positions;       /* vertex_count * 3: bind-space positions of the merged vertex stream */
    const float* normals;         /* vertex_count * 3, or NULL */
    const uint32_t* triangles;    /* triangle_count * 3 vertex indices */
    const uint16_t* joints;       /* vertex_count * influences: progressive bone of each influence */
    const float* weights;         /* vertex_count * influences */
    uint64_t id;                  /* content hash */
    double diagonal;              /* rest-pose bounding box diagonal (model units) */
    int32_t bone_count;           /* B, the palette's length */
    int32_t joint_count;          /* joints of the glTF skin (psk_client_publish takes this many) */
    int32_t vertex_count;
    int32_t triangle_count;
    int32_t influences;
    int32_t morph_count;
    int32_t clip_count;
    int32_t ready;                /* 0: not downloaded yet (only name is set) */
} psk_asset;

/* What psk_client_spawn asks of the server: fill with psk_spawn_spec_init. */
typedef struct psk_spawn_spec {
    double walk_center[3];  /* announced walk (observers' reference); radius 0: none */
    double walk_radius;
    double walk_speed;
    const int32_t* clips;   /* clip indices announced to observers (may be NULL) */
    uint64_t start_us;      /* publisher clock at clip start */
    float position[3];
    float speed;            /* clip speed (default 1) */
    int32_t clip_count;     /* at most 64 */
    int32_t asset;          /* index into the catalogue */
    int32_t once;           /* the clip plays once and holds */
    int32_t reserved;
} psk_spawn_spec;

/* A character's root in the world (psk_client_publish). */
typedef struct psk_root {
    double position[3];
    uint64_t source_us;  /* the publisher's clock (microseconds), e.g. psk_now() * 1e6 */
    float rotation[4];   /* quaternion x y z w (0 0 0 1: none) */
} psk_root;

/* The client's view (psk_client_set_view): where the camera is, and
 * optional explicit weights per instance, for the server's level of detail. */
typedef struct psk_view {
    const int32_t* weight_instances; /* weight_count instance ids, or NULL */
    const float* weights;            /* weight_count weights, or NULL */
    float camera[3];
    float fov_y;                     /* radians (default 0.8) */
    float viewport_height;           /* pixels (default 1080) */
    int32_t has_camera;
    int32_t weight_count;            /* at most 65536 */
    int32_t reserved;
} psk_view;

typedef struct psk_stats {
    double seconds;          /* since the first frame */
    double loss;             /* fraction of datagrams lost */
    double rtt_ms;
    double estimate_kbps;    /* the server's rate estimate */
    double delay_ms;         /* largest display delay used */
    double download_seconds; /* until every asset was ready; -1: not yet */
    uint64_t datagrams;
    uint64_t wire_bytes;     /* bytes received (payload + 28 per datagram) */
    uint64_t asset_bytes_downloaded;
    uint64_t poses_sent;
    uint64_t poses_refused;
    int32_t assets_cached;
    int32_t reserved;
} psk_stats;

/* --- Library ------------------------------------------------------------ */

PSK_API const char* psk_version(void);         /* "0.1.0" */
PSK_API uint32_t psk_version_number(void);     /* as PSK_VERSION_NUMBER */
PSK_API double psk_now(void);                  /* monotonic seconds: the clock of psk_client_update */
PSK_API const char* psk_last_error(void);      /* this thread's last message; never NULL */
PSK_API const char* psk_status_name(int status); /* "PSK_OK", "PSK_ERR_NULL", ... */

/* --- Client ------------------------------------------------------------- */

PSK_API psk_status psk_client_config_init(psk_client_config* config);
/* A client, not connected; NULL on failure (psk_last_error says why). */
PSK_API psk_client* psk_client_create(const psk_client_config* config);
/* Closes the connection and frees the client; NULL is a no-op. */
PSK_API psk_status psk_client_destroy(psk_client* client);

/* Starts connecting (once per client). host is resolved at once: pass a
 * numeric address never to block. PSK_ERR_FAILED when the configuration
 * cannot connect (TLS with nothing to trust the certificate by, ...). */
PSK_API psk_status psk_client_connect(psk_client* client, const char* host, uint16_t port);
/* Failover: servers is "HOST:PORT[,HOST:PORT...]" (the servers of one world,
 * serving the same catalogue). Connects to the first; when a server is lost
 * (closed, its goodbye, a timeout, a refusal) the client connects to the
 * next within the same psk_client_update, spawns its characters again and
 * raises PSK_EVENT_FAILED_OVER; each server is tried once per loss.
 * PSK_ERR_ARGUMENT for a list that is not HOST:PORT entries. */
PSK_API psk_status psk_client_connect_list(psk_client* client, const char* servers);
/* Once per game frame; never blocks. now: psk_now()'s clock. Does the
 * socket I/O, downloads, acks, and the palettes of every character.
 * PSK_ERR_FAILED once the client is Failed. No allocation once steady. */
PSK_API psk_status psk_client_update(psk_client* client, double now);
/* Says goodbye (reason may be NULL); the client stays valid until destroyed. */
PSK_API psk_status psk_client_close(psk_client* client, const char* reason);

PSK_API psk_status psk_client_state(const psk_client* client, psk_state* state);
PSK_API psk_status psk_client_fail_reason(const psk_client* client, psk_fail_reason* reason);
/* The events the last update raised, one per call, in order: PSK_OK and
 * *event filled, or PSK_EMPTY when none is left. */
PSK_API psk_status psk_client_poll_event(psk_client* client, psk_event* event);

PSK_API psk_status psk_client_character_count(const psk_client* client, int* count);
/* Character index (0 <= index < count, ordered by instance id). */
PSK_API psk_status psk_client_character(const psk_client* client, int index, psk_character* character);
/* The character with this instance id: PSK_ERR_ARGUMENT when unknown. */
PSK_API psk_status psk_client_find_character(const psk_client* client, int instance, psk_character* character);
/* The character's id across a world of servers (the same on every node, never
 * reused; instance ids are per server): *world_id, 0 from a server that sends
 * none. PSK_ERR_ARGUMENT when no character has this instance id. */
PSK_API psk_status psk_client_character_world_id(const psk_client* client, int instance, uint64_t* world_id);

/* The server's catalogue (known once Connected). */
PSK_API psk_status psk_client_asset_count(const psk_client* client, int* count);
/* Asset index: PSK_OK, or PSK_NOT_READY (only name set, ready 0) until downloaded. */
PSK_API psk_status psk_client_asset(psk_client* client, int index, psk_asset* asset);
/* Skinning matrices of every joint (joint_count * 12 floats, glTF joint
 * order, relative to the root) of an asset's clip at time t seconds after
 * its start, looped: what psk_client_publish takes. clip -1: every clip of
 * the asset played together. capacity: floats in out. */
PSK_API psk_status psk_client_sample_clip(psk_client* client, int asset, int clip, double t, float* out,
                                          int capacity);

PSK_API psk_status psk_spawn_spec_init(psk_spawn_spec* spec);
/* Asks the server for a character; *handle identifies it. The answer comes
 * as a PSK_EVENT_SPAWNED or PSK_EVENT_SPAWN_REFUSED event. Connected only. */
PSK_API psk_status psk_client_spawn(psk_client* client, const psk_spawn_spec* spec, int* handle);
/* The instance a handle owns (-1 until Spawned). */
PSK_API psk_status psk_client_instance_of(const psk_client* client, int handle, int* instance);
/* The newest pose of a spawned character: skinning (joint_count * 12 floats,
 * the asset's joint_count, glTF joint order, relative to the root), the root,
 * and optionally morph weights (morph_count, the asset's targets; NULL/0:
 * none). PSK_OK: sent; PSK_NOT_READY: not spawned yet or the stream not
 * bound; PSK_ERR_ARGUMENT: a count is wrong or a value outside the codec's
 * range (nothing is clamped). */
PSK_API psk_status psk_client_publish(psk_client* client, int handle, const psk_root* root, const float* skinning,
                                      int joint_count, const float* morph_weights, int morph_count, int teleport);
PSK_API psk_status psk_client_despawn(psk_client* client, int handle);

PSK_API psk_status psk_client_set_view(psk_client* client, const psk_view* view);
/* kbps >= 0 (0: the server's maximum). */
PSK_API psk_status psk_client_set_max_kbps(psk_client* client, double kbps);
/* Copies the statistics (not for every frame: it copies a history). */
PSK_API psk_status psk_client_stats(const psk_client* client, psk_stats* stats);

#ifdef __cplusplus
}
#endif

#endif /* PROGSKIN_PROGSKIN_H */
