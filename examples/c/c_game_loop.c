/* c_game_loop.c — a game's loop in C around the progskin C API (progskin.h,
 * libprogskin_c.so): connect, spawn one character of the server's catalogue
 * and publish its pose every frame (its clip, walking a circle), and print
 * the other characters once a second. No thread of its own: one
 * psk_client_update per frame. The same program as examples/game_loop.cpp.
 *
 *   progskin-server --no-scene &        # prints "TLS certificate sha256 HEX"
 *   c_game_loop 127.0.0.1 7777 [SECONDS [HEX]]
 * With HEX the control channel is TLS pinned to that certificate; without
 * it, plain TCP (a server started with --no-tls). */
#define _POSIX_C_SOURCE 199309L
#include <progskin/progskin.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static void sleep_ms(int ms) {
    struct timespec ts;
    ts.tv_sec = 0;
    ts.tv_nsec = (long)ms * 1000000L;
    nanosleep(&ts, NULL);
}

static int die(const char* what) {
    fprintf(stderr, "c_game_loop: %s: %s\n", what, psk_last_error());
    return 1;
}

static void print_characters(psk_client* c) {
    int n = 0, i;
    psk_client_character_count(c, &n);
    for (i = 0; i < n; ++i) {
        psk_character ch;
        psk_asset a;
        if (psk_client_character(c, i, &ch) != PSK_OK || !ch.shown) continue;
        psk_client_asset(c, ch.asset, &a);
        /* A renderer would upload ch.palette (ch.bone_count * 12 floats) as bone matrices. */
        printf("character %d (%s): %d of %d bones at (%.2f, %.2f, %.2f)\n", (int)ch.instance, a.name, (int)ch.bones,
               (int)ch.bone_count, ch.position[0], ch.position[1], ch.position[2]);
    }
    fflush(stdout);
}

int main(int argc, char** argv) {
    psk_client_config cfg;
    psk_client* c;
    psk_event e;
    psk_asset asset;
    float* skin = NULL;
    int handle = -1, instance = -1, joints = 0, rc = 0;
    double start, next_print, seconds;
    if (argc < 3 || strcmp(argv[1], "--help") == 0) {
        fprintf(argc < 3 ? stderr : stdout, "usage: c_game_loop HOST PORT [SECONDS [SHA256]]\n"
                "Joins a progskin-server, publishes one walking character and prints the others.\n");
        return argc < 3 ? 2 : 0;
    }
    seconds = argc > 3 ? atof(argv[3]) : 10.0;
    psk_client_config_init(&cfg);
    cfg.tls = argc > 4;          /* TLS, trusting the certificate with this fingerprint */
    cfg.pin_sha256 = argc > 4 ? argv[4] : NULL;
    c = psk_client_create(&cfg);
    if (!c) return die("create");
    if (psk_client_connect(c, argv[1], (uint16_t)atoi(argv[2])) != PSK_OK) {
        psk_client_destroy(c);
        return die("connect");
    }
    start = psk_now();
    next_print = start + 1.0;
    while (psk_now() - start < seconds) {
        const double now = psk_now();
        if (psk_client_update(c, now) != PSK_OK) {
            rc = die("update");
            break;
        }
        while (psk_client_poll_event(c, &e) == PSK_OK) {
            if (e.type == PSK_EVENT_CHARACTER_ADDED) printf("+ character %d\n", (int)e.instance);
            if (e.type == PSK_EVENT_CHARACTER_REMOVED) printf("- character %d\n", (int)e.instance);
            if (e.type == PSK_EVENT_SPAWNED) printf("I am character %d\n", (int)e.instance);
            if (e.type == PSK_EVENT_SPAWN_REFUSED) fprintf(stderr, "spawn refused: %s\n", e.text);
        }
        /* Spawn once the catalogue's first asset is here. */
        if (handle < 0 && psk_client_asset(c, 0, &asset) == PSK_OK) {
            psk_spawn_spec spec;
            psk_spawn_spec_init(&spec);
            spec.asset = 0;
            joints = asset.joint_count;
            skin = (float*)malloc(sizeof(float) * 12 * (size_t)joints);
            if (!skin || psk_client_spawn(c, &spec, &handle) != PSK_OK) {
                rc = die("spawn");
                break;
            }
        }
        /* My pose this frame: every clip of the asset at my time, walking a circle of 5 diagonals. */
        if (handle >= 0 && instance < 0) psk_client_instance_of(c, handle, &instance);
        if (instance >= 0) {
            const double t = now - start, r = 5.0 * asset.diagonal, w = 0.15;
            psk_root root;
            memset(&root, 0, sizeof root);
            root.position[0] = r * cos(w * t);
            root.position[2] = r * sin(w * t);
            root.rotation[1] = (float)sin(-0.5 * w * t); /* turning about y as it walks */
            root.rotation[3] = (float)cos(-0.5 * w * t);
            root.source_us = (uint64_t)(now * 1e6);
            psk_client_sample_clip(c, 0, -1, t, skin, 12 * joints);
            psk_client_publish(c, handle, &root, skin, joints, NULL, 0, 0); /* PSK_NOT_READY until bound */
        }
        if (now >= next_print) {
            next_print += 1.0;
            print_characters(c);
        }
        sleep_ms(16); /* the game's frame */
    }
    psk_client_close(c, "done");
    psk_client_destroy(c);
    free(skin);
    return rc;
}
