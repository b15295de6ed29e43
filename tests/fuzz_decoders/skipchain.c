/* Planted-bug decoder for the fuzzer's acceptance test (tests/integration/test_fuzz.py): a face object
 * stream front-end that parses plane headers (the first plane and every plane after a plane
 * start code) and then reports the payload as not supported (exit 69). Rejects what it cannot
 * parse with exit 2.
 *
 * `skipchain --serve` speaks fbaconf's persistent protocol (one process, many inputs).
 *
 * THE BUG: a frame table of 256 entries is indexed by the frame number, which includes
 * number_of_frames_to_skip, without a bounds check: a large skip chain writes far out of
 * bounds (SIGSEGV). Never ship this. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct frame { int values[68]; };

static const unsigned char *buf;
static long nbits, pos;

static int rd(int n, unsigned long *out) {
    unsigned long v = 0;
    if (pos + n > nbits) return -1;
    for (int i = 0; i < n; i++, pos++)
        v = (v << 1) | ((buf[pos >> 3] >> (7 - (pos & 7))) & 1);
    *out = v;
    return 0;
}

static struct frame *frames;
static long frame_number = -1;

static int plane(void) {
    unsigned long intra, mask, f, v;
    if (rd(1, &intra) || rd(2, &mask)) return -1;
    if (mask != 1) return -1;
    if (intra) {
        if (rd(1, &f)) return -1;
        if (f && rd(13, &v)) return -1;
        if (rd(1, &f)) return -1;
        if (f && rd(18, &v)) return -1;
    }
    long skip = 0;
    if (rd(1, &f)) return -1;
    if (f) {
        do {
            if (rd(4, &v)) return -1;
            skip += (long)v;
        } while (v == 15);
    }
    frame_number += skip + 1;
#ifdef SKIPCHAIN_FIXED  /* the same program without its bug (benchmarks/bench_fuzz.py) */
    if (frame_number >= 256) return -1;
#endif
    frames[frame_number].values[0] = 1;   /* BUG: no check against the 256-entry table */
    return 0;
}

/* One stream in memory: 2 = reject, 69 = headers parsed, payload not supported. */
static int decode(unsigned char *data, long size) {
    buf = data;
    nbits = size * 8;
    frame_number = -1;
    memset(frames, 0, 256 * sizeof(struct frame));
    if (size < 4 || memcmp(data, "\x00\x00\x01\xba", 4) != 0) {
        fprintf(stderr, "skipchain: not a face object stream\n");
        return 2;
    }
    pos = 32;
    /* plane 0 directly after the object start code, unless a plane start code precedes it */
    if (!(size >= 9 && memcmp(data + 4, "\x7f\x00\x00\x01\xbb", 5) == 0) && plane() != 0) {
        fprintf(stderr, "skipchain: bad plane header\n");
        return 2;
    }
    for (long i = 4; i + 4 <= size; i++) {
        if (memcmp(data + i, "\x00\x00\x01\xbb", 4) == 0) {
            pos = (i + 4) * 8;
            if (plane() != 0) { fprintf(stderr, "skipchain: bad plane header\n"); return 2; }
        }
    }
    fprintf(stderr, "skipchain: headers parsed; payload decoding not supported\n");
    return 69;
}

/* fbaconf's persistent protocol (docs/harness.md): "<size> <output path>\n" + size bytes in,
 * "<code>\n" out, until end of input. */
static int serve(void) {
    char line[4096];
    while (fgets(line, sizeof line, stdin)) {
        char *end;
        unsigned long id = strtoul(line, &end, 10);
        long size = strtol(end, NULL, 10);
        if (size < 0 || size > (64L << 20)) return 2;
        unsigned char *data = malloc(size > 0 ? size : 1);
        if (fread(data, 1, size, stdin) != (size_t)size) { free(data); return 2; }
        int code = decode(data, size);
        free(data);
        printf("%lu %d\n", id, code);
        fflush(stdout);
    }
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 2) { fprintf(stderr, "usage: skipchain IN.fba [OUT] | skipchain --serve\n"); return 2; }
    frames = calloc(256, sizeof(struct frame));
    if (strcmp(argv[1], "--serve") == 0) return serve();
    FILE *fp = fopen(argv[1], "rb");
    if (!fp) { perror(argv[1]); return 2; }
    fseek(fp, 0, SEEK_END);
    long size = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    unsigned char *data = malloc(size > 0 ? size : 1);
    if (fread(data, 1, size, fp) != (size_t)size) { fclose(fp); return 2; }
    fclose(fp);
    return decode(data, size);
}
