/* test_capi_loopback.c — the C API (progskin.h) against a real
 * progskin-server on loopback, run by tests/with_server.py (TLS pinned to the
 * server's certificate, sealed datagrams): an observer connects and sees
 * every character of the scene within 2 s; a player connects, spawns a
 * character of the catalogue and publishes it from its clip, and the
 * observer sees it within 2 s of the spawn; bad input gets statuses and
 * messages. C99, built with -pedantic; exit 0 when every check holds. */
#define _POSIX_C_SOURCE 199309L
#include <progskin/progskin.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static int failures = 0;

#define CHECK(cond, ...)                                                  \
    do {                                                                  \
        if (!(cond)) {                                                    \
            ++failures;                                                   \
            fprintf(stderr, "FAIL %s:%d: %s: ", __FILE__, __LINE__, #cond); \
            fprintf(stderr, __VA_ARGS__);                                 \
            fprintf(stderr, " (last error: %s)\n", psk_last_error());     \
        }                                                                 \
    } while (0)

static void sleep_ms(int ms) {
    struct timespec ts;
    ts.tv_sec = ms / 1000;
    ts.tv_nsec = (long)(ms % 1000) * 1000000L;
    nanosleep(&ts, NULL);
}

static const char* env(const char* name) {
    const char* v = getenv(name);
    if (!v) {
        fprintf(stderr, "test_capi_loopback: %s is not set (run it with tests/with_server.py)\n", name);
        exit(2);
    }
    return v;
}

static psk_client* connect_client(const char* name) {
    psk_client_config cfg;
    psk_client* c;
    psk_status s;
    CHECK(psk_client_config_init(&cfg) == PSK_OK, "config_init");
    CHECK(cfg.tls == 1 && cfg.delay_ms > 0, "defaults: tls %d, delay_ms %g", (int)cfg.tls, cfg.delay_ms);
    cfg.name = name;
    cfg.pin_sha256 = env("PROGSKIN_PIN");
    cfg.cache_dir = env("PROGSKIN_CACHE");
    c = psk_client_create(&cfg);
    if (!c) {
        fprintf(stderr, "psk_client_create: %s\n", psk_last_error());
        exit(1);
    }
    if (strcmp(name, "c-player") == 0) {
        /* The player names a second server to fail over to (never needed here). */
        char list[300];
        CHECK(psk_client_connect_list(c, "127.0.0.1:7777,nope") == PSK_ERR_ARGUMENT &&
                  strstr(psk_last_error(), "'nope' is not HOST:PORT"),
              "a bad server list: %s", psk_last_error());
        snprintf(list, sizeof list, "%s:%s,127.0.0.1:1", env("PROGSKIN_HOST"), env("PROGSKIN_PORT"));
        s = psk_client_connect_list(c, list);
    } else {
        s = psk_client_connect(c, env("PROGSKIN_HOST"), (uint16_t)atoi(env("PROGSKIN_PORT")));
    }
    CHECK(s == PSK_OK, "connect: %s", psk_status_name(s));
    return c;
}

/* Shown characters with a finite palette of every bone; *published: the
 * instance of one published by a player (-1 when none). */
static int count_shown(psk_client* c, int* published) {
    int n = 0, i, shown = 0;
    *published = -1;
    CHECK(psk_client_character_count(c, &n) == PSK_OK, "character_count");
    for (i = 0; i < n; ++i) {
        psk_character ch;
        int b;
        if (psk_client_character(c, i, &ch) != PSK_OK || !ch.shown) continue;
        CHECK(ch.palette != NULL && ch.bone_count > 0 && ch.bones >= 1 && ch.bones <= ch.bone_count,
              "character %d: palette %p, %d of %d bones", (int)ch.instance, (const void*)ch.palette, (int)ch.bones,
              (int)ch.bone_count);
        for (b = 0; ch.palette && b < ch.bone_count * 12; ++b)
            if (!isfinite(ch.palette[b])) {
                CHECK(0, "character %d: palette float %d is not finite", (int)ch.instance, b);
                break;
            }
        CHECK(ch.asset >= 0, "character %d: asset %d", (int)ch.instance, (int)ch.asset);
        {
            uint64_t world_id = 0;
            CHECK(psk_client_character_world_id(c, ch.instance, &world_id) == PSK_OK && world_id != 0,
                  "character %d: world id %llu", (int)ch.instance, (unsigned long long)world_id);
        }
        if (ch.published) *published = ch.instance;
        ++shown;
    }
    return shown;
}

static void step(psk_client* c, double now) {
    psk_event e;
    psk_status s = psk_client_update(c, now);
    CHECK(s == PSK_OK, "update: %s", psk_status_name(s));
    if (s != PSK_OK) exit(1);
    while (psk_client_poll_event(c, &e) == PSK_OK)
        if (e.type == PSK_EVENT_SPAWN_REFUSED || e.type == PSK_EVENT_FAILED) CHECK(0, "event %d: %s", (int)e.type, e.text);
}

/* Bad input: statuses and messages, never a crash. */
static void check_bad_input(psk_client* c) {
    psk_character ch;
    psk_asset a;
    psk_state st;
    int n;
    CHECK(psk_client_character(c, -1, &ch) == PSK_ERR_ARGUMENT && strstr(psk_last_error(), "index -1"), "index -1");
    CHECK(psk_client_character(c, 1000000, &ch) == PSK_ERR_ARGUMENT, "index 1000000");
    CHECK(psk_client_character(NULL, 0, &ch) == PSK_ERR_NULL && strstr(psk_last_error(), "NULL"), "NULL client");
    CHECK(psk_client_character(c, 0, NULL) == PSK_ERR_NULL, "NULL out");
    CHECK(psk_client_asset(c, 99, &a) == PSK_ERR_ARGUMENT, "asset 99");
    CHECK(psk_client_connect(c, "127.0.0.1", 1) == PSK_ERR_STATE, "connect twice");
    CHECK(psk_client_update(c, NAN) == PSK_ERR_ARGUMENT, "update NaN");
    CHECK(psk_client_set_max_kbps(c, -1) == PSK_ERR_ARGUMENT, "max_kbps -1");
    CHECK(psk_client_publish(c, 12345, NULL, NULL, 0, NULL, 0, 0) == PSK_ERR_NULL &&
              strstr(psk_last_error(), "psk_client_publish: root is NULL"),
          "publish NULL names the function and the argument");
    CHECK(psk_client_connect(NULL, "127.0.0.1", 1) == PSK_ERR_NULL &&
              strstr(psk_last_error(), "psk_client_connect: client is NULL"),
          "connect NULL names the function");
    CHECK(psk_client_state(c, &st) == PSK_OK && st == PSK_STATE_STREAMING, "state %d", (int)st);
    CHECK(psk_client_state(c, NULL) == PSK_ERR_NULL, "state NULL");
    CHECK(psk_client_create(NULL) == NULL && strlen(psk_last_error()) > 0, "create NULL");
    CHECK(psk_client_destroy(NULL) == PSK_OK, "destroy NULL");
    CHECK(psk_client_asset_count(c, &n) == PSK_OK && strlen(psk_last_error()) == 0, "success clears the error");
}

int main(void) {
    const int instances = atoi(env("PROGSKIN_INSTANCES"));
    psk_client* observer;
    psk_client* player;
    double t0, all_seen = -1, spawned_at = -1, seen_published = -1;
    int handle = -1, instance = -1, published = -1, shown = 0, joints = 0, n;
    float* skin = NULL;
    psk_asset asset;

    printf("progskin C API %s (header %d.%d.%d)\n", psk_version(), PSK_VERSION_MAJOR, PSK_VERSION_MINOR,
           PSK_VERSION_PATCH);
    CHECK(psk_version_number() == PSK_VERSION_NUMBER, "library %x, header %x", (unsigned)psk_version_number(),
          (unsigned)PSK_VERSION_NUMBER);
    t0 = psk_now();
    observer = connect_client("c-observer");
    /* 1. The observer sees every character of the scene within 2 s. */
    while (psk_now() - t0 < 5 && all_seen < 0) {
        step(observer, psk_now());
        if (count_shown(observer, &published) == instances) all_seen = psk_now() - t0;
        sleep_ms(10);
    }
    CHECK(all_seen >= 0 && all_seen <= 2.0, "saw all %d characters after %.3f s", instances, all_seen);
    printf("observer: all %d characters shown %.3f s after connect\n", instances, all_seen);
    check_bad_input(observer);

    /* 2. A player spawns a character and publishes it from its clip. */
    player = connect_client("c-player");
    t0 = psk_now();
    while (psk_now() - t0 < 8 && seen_published < 0) {
        const double now = psk_now();
        step(player, now);
        step(observer, now);
        if (handle < 0 && psk_client_asset(player, 0, &asset) == PSK_OK) {
            psk_spawn_spec spec;
            psk_spawn_spec_init(&spec);
            spec.asset = 0;
            CHECK(psk_client_spawn(player, &spec, &handle) == PSK_OK, "spawn");
            CHECK(asset.bone_count > 0 && asset.order && asset.parents && asset.parents[0] == -1 && asset.inverse_binds &&
                      asset.path && strlen(asset.path) > 0 && asset.vertex_count > 0 && asset.joints && asset.weights,
                  "asset 0 (%s): %d bones, path %s", asset.name, (int)asset.bone_count, asset.path ? asset.path : "-");
            joints = asset.joint_count;
            skin = (float*)malloc(sizeof(float) * 12 * (size_t)joints);
            spawned_at = now;
        }
        if (handle >= 0 && instance < 0) psk_client_instance_of(player, handle, &instance);
        if (instance >= 0) {
            psk_root root;
            psk_status s;
            memset(&root, 0, sizeof root);
            root.position[0] = 3.0 * cos(now);
            root.position[2] = 3.0 * sin(now);
            root.rotation[3] = 1;
            root.source_us = (uint64_t)(now * 1e6);
            CHECK(psk_client_sample_clip(player, 0, -1, now - spawned_at, skin, 12 * joints) == PSK_OK, "sample");
            s = psk_client_publish(player, handle, &root, skin, joints, NULL, 0, 0);
            CHECK(s == PSK_OK || s == PSK_NOT_READY, "publish: %s", psk_status_name(s));
            CHECK(psk_client_publish(player, handle, &root, skin, joints - 1, NULL, 0, 0) == PSK_ERR_ARGUMENT,
                  "publish with the wrong joint count");
            if (s == PSK_OK) { /* values publish refuses are named (spawned and bound: the checks come after those) */
                psk_root zero = root;
                const float keep = skin[12 * (joints - 1) + 3];
                zero.rotation[3] = 0;
                CHECK(psk_client_publish(player, handle, &zero, skin, joints, NULL, 0, 0) == PSK_ERR_ARGUMENT &&
                          strstr(psk_last_error(), "zero quaternion"),
                      "a zero root rotation is named: %s", psk_last_error());
                skin[12 * (joints - 1) + 3] = (float)NAN;
                CHECK(psk_client_publish(player, handle, &root, skin, joints, NULL, 0, 0) == PSK_ERR_ARGUMENT &&
                          strstr(psk_last_error(), "joint"),
                      "a NaN in a skinning matrix names the joint: %s", psk_last_error());
                skin[12 * (joints - 1) + 3] = keep;
            }
        }
        shown = count_shown(observer, &published);
        if (published >= 0 && published == instance) seen_published = now - spawned_at;
        sleep_ms(10);
    }
    CHECK(instance >= 0, "the player's spawn was confirmed");
    CHECK(seen_published >= 0 && seen_published <= 2.0, "observer saw the published character %.3f s after the spawn",
          seen_published);
    CHECK(shown == instances + 1, "observer shows %d characters, expected %d", shown, instances + 1);
    /* The observer can show the player's character before the player shows
       the whole scene (it joined a moment ago): within 2 s more. */
    {
        const double t1 = psk_now();
        int player_shows = count_shown(player, &published);
        while (player_shows < instances && psk_now() - t1 < 2.0) {
            step(player, psk_now());
            step(observer, psk_now());
            player_shows = count_shown(player, &published);
            sleep_ms(10);
        }
        CHECK(player_shows == instances && published < 0, "the player sees the scene (%d of %d), not itself",
              player_shows, instances);
    }
    printf("observer: the player's character %d shown %.3f s after its spawn\n", instance, seen_published);

    CHECK(psk_client_despawn(player, handle) == PSK_OK, "despawn");
    CHECK(psk_client_close(player, "bye") == PSK_OK && psk_client_close(observer, NULL) == PSK_OK, "close");
    CHECK(psk_client_character_count(observer, &n) == PSK_OK, "count after close");
    CHECK(psk_client_destroy(player) == PSK_OK && psk_client_destroy(observer) == PSK_OK, "destroy");
    free(skin);
    if (failures) fprintf(stderr, "test_capi_loopback: %d check(s) failed\n", failures);
    else printf("test_capi_loopback: every check passed\n");
    return failures ? 1 : 0;
}
