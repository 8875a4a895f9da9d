// SPDX-License-Identifier: BSD-3-Clause
// Evenly paced VLP-16 UDP sender for bench/daemon.py (compiled there with cc into a temp dir).
//
// Sends real VLP-16 data payloads (a file of 1206-byte payloads back to back, cycled, see vary),
// packet i at t0 + i / rate on CLOCK_MONOTONIC: it sleeps to the next packet's absolute deadline
// (clock_nanosleep TIMER_ABSTIME, timer slack 1 ns) and then sends every packet that is due
// with one sendmmsg, so packets leave as evenly as the scheduler wakes it (tens of µs), never
// in bursts of a fixed size. Each packet carries its number i (+ first) as a u32 in bytes
// 1196..1199 (the last block's last channel record) and a device timestamp (bytes 1200..1203,
// µs past the hour) of i / rate, so the daemon's clock estimator sees a steady sensor.
//
// usage: paced_sender HOST PORT RATE SECONDS FIRST PAYLOADS [KILL_PID KILL_AT_S]
// prints: sent N elapsed_s E rate R calls C max_late_us L [killed_after K]
// Without KILL_PID a last packet follows 0.2 s after the run (the kernel reports its drop count
// with the next datagram it queues). With it, SIGKILL goes to KILL_PID once KILL_AT_S into the
// run, after the packets due before then were sent, and sending stops.
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <time.h>

#define PAYLOAD 1206
#define MAXB 256

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

// Each pass over the payload file moves every return by `cycle` distance units (2 mm): the
// data stay lidar-like but never repeat exactly, so compression sees fresh data, as from the
// sensor, not a 1000-packet loop it could match.
static void vary(unsigned char *p, uint16_t cycle) {
    for (int b = 0; b < 12; b++) {
        for (int c = 0; c < 32; c++) {
            unsigned char *d = p + b * 100 + 4 + c * 3;
            uint16_t v = (uint16_t)(d[0] | d[1] << 8);
            if (v) {
                v = (uint16_t)(v + cycle);
                d[0] = (unsigned char)v;
                d[1] = (unsigned char)(v >> 8);
            }
        }
    }
}

int main(int argc, char **argv) {
    if (argc != 7 && argc != 9) {
        fprintf(stderr, "usage: %s HOST PORT RATE SECONDS FIRST PAYLOADS [KILL_PID KILL_AT_S]\n",
                argv[0]);
        return 2;
    }
    const char *host = argv[1];
    int port = atoi(argv[2]);
    double rate = atof(argv[3]), seconds = atof(argv[4]);
    uint32_t first = (uint32_t)strtoul(argv[5], NULL, 10);
    pid_t kill_pid = argc == 9 ? (pid_t)atol(argv[7]) : 0;
    double kill_at = argc == 9 ? atof(argv[8]) : 0.0;
    FILE *f = fopen(argv[6], "rb");
    if (!f) { perror(argv[6]); return 2; }
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, 0, SEEK_SET);
    int npay = (int)(size / PAYLOAD);
    if (npay < 1) { fprintf(stderr, "%s: no 1206-byte payloads\n", argv[6]); return 2; }
    unsigned char *pay = malloc((size_t)npay * PAYLOAD);
    if (fread(pay, PAYLOAD, (size_t)npay, f) != (size_t)npay) { perror("read"); return 2; }
    fclose(f);

    int s = socket(AF_INET, SOCK_DGRAM, 0);
    int sndbuf = 4 << 20;
    setsockopt(s, SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof sndbuf);
    struct sockaddr_in to = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    inet_pton(AF_INET, host, &to.sin_addr);
    if (connect(s, (struct sockaddr *)&to, sizeof to) != 0) { perror("connect"); return 2; }
    prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);

    static unsigned char buf[MAXB][PAYLOAD];
    struct iovec iov[MAXB];
    struct mmsghdr msgs[MAXB];
    memset(msgs, 0, sizeof msgs);
    for (int k = 0; k < MAXB; k++) {
        iov[k].iov_base = buf[k];
        iov[k].iov_len = PAYLOAD;
        msgs[k].msg_hdr.msg_iov = &iov[k];
        msgs[k].msg_hdr.msg_iovlen = 1;
    }
    uint64_t n = (uint64_t)(rate * seconds);
    double period_ns = 1e9 / rate;
    uint64_t kill_i = kill_pid ? (uint64_t)(kill_at * rate) : n + 1;
    if (kill_i > n) kill_i = n + 1;
    uint64_t i = 0, calls = 0;
    int64_t max_late = 0;
    int64_t t0 = now_ns() + 1000000;  // start 1 ms from now
    long long killed_after = -1;
    while (i < n) {
        int64_t t = now_ns();
        int64_t el = t - t0;
        uint64_t due = el < 0 ? 0 : (uint64_t)((double)el / period_ns) + 1;
        if (due > n) due = n;
        if (due > kill_i) due = kill_i;
        if (due <= i) {
            if (i == kill_i) {
                kill(kill_pid, SIGKILL);
                killed_after = (long long)i;
                break;
            }
            int64_t dl = t0 + (int64_t)((double)i * period_ns);
            struct timespec ts = {.tv_sec = dl / 1000000000LL, .tv_nsec = dl % 1000000000LL};
            clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL);
            continue;
        }
        int64_t late = el - (int64_t)((double)i * period_ns);
        if (late > max_late) max_late = late;
        while (i < due) {
            int k = 0;
            for (; k < MAXB && i + (uint64_t)k < due; k++) {
                uint64_t seq = i + (uint64_t)k;
                uint32_t num = first + (uint32_t)seq;
                memcpy(buf[k], pay + (size_t)(seq % (uint64_t)npay) * PAYLOAD, PAYLOAD);
                uint16_t cycle = (uint16_t)(seq / (uint64_t)npay);
                if (cycle) vary(buf[k], cycle);
                uint32_t toh = (uint32_t)((uint64_t)((double)seq * period_ns / 1000.0)
                                          % 3600000000ULL);
                memcpy(buf[k] + 1196, &num, 4);
                memcpy(buf[k] + 1200, &toh, 4);
            }
            int off = 0;
            while (off < k) {
                int r = sendmmsg(s, msgs + off, (unsigned)(k - off), 0);
                if (r < 0) { perror("sendmmsg"); return 1; }
                off += r;
            }
            calls++;
            i += (uint64_t)k;
        }
    }
    if (i == kill_i && killed_after < 0 && kill_pid) {
        kill(kill_pid, SIGKILL);
        killed_after = (long long)i;
    }
    double elapsed = (double)(now_ns() - t0) / 1e9;
    if (!kill_pid) {  // one more packet a little later: it carries the kernel's drop count
        struct timespec d = {0, 200000000};
        nanosleep(&d, NULL);
        memcpy(buf[0], pay, PAYLOAD);
        uint32_t num = first + (uint32_t)n;
        memcpy(buf[0] + 1196, &num, 4);
        send(s, buf[0], PAYLOAD, 0);
        i++;
    }
    printf("sent %llu elapsed_s %.6f rate %.1f calls %llu max_late_us %.0f",
           (unsigned long long)i, elapsed, (double)(kill_pid ? i : i - 1) / elapsed,
           (unsigned long long)calls, (double)max_late / 1e3);
    if (killed_after >= 0) printf(" killed_after %lld", killed_after);
    printf("\n");
    return 0;
}
