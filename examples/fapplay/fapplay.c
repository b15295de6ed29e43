/* fapplay: a tiny "player" for the .fap text form, written as the worked adapter example of
 * docs/harness.md. It reads IN.fap, keeps the FAP state the way a player does (a FAP not
 * sent in a frame keeps its last value), and writes OUT.fap with every FAP it holds.
 *
 *   cc -O2 -o fapplay fapplay.c && ./fapplay IN.fap OUT.fap
 *
 * Exit codes: 0 done, 1 unreadable input (message on stderr), 69 not supported.
 */
#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NFAP 68

static FILE *in;
static int line_no = 1;

/* next whitespace-separated token, skipping '#' comments; returns 0 at end of file */
static int token(char *buf, size_t n) {
    int c;
    size_t k = 0;
    for (;;) {
        c = fgetc(in);
        if (c == EOF) return 0;
        if (c == '\n') line_no++;
        if (c == '#') {
            while ((c = fgetc(in)) != EOF && c != '\n') {}
            if (c == '\n') line_no++;
            continue;
        }
        if (!isspace(c)) break;
    }
    do {
        if (k + 1 < n) buf[k++] = (char)c;
        c = fgetc(in);
    } while (c != EOF && !isspace(c) && c != '#');
    if (c == '\n') line_no++;
    if (c == '#') ungetc(c, in);
    buf[k] = 0;
    return 1;
}

static long integer(const char *what) {
    char buf[64], *end;
    if (!token(buf, sizeof buf)) {
        fprintf(stderr, "fapplay: line %d: end of file, expected %s\n", line_no, what);
        exit(1);
    }
    long v = strtol(buf, &end, 10);
    if (*end) {
        fprintf(stderr, "fapplay: line %d: %s is not an integer: %s\n", line_no, what, buf);
        exit(1);
    }
    return v;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: fapplay IN.fap OUT.fap\n");
        return 2;
    }
    in = fopen(argv[1], "r");
    if (!in) { perror(argv[1]); return 1; }
    char version[64], name[256], tok[256];
    if (!token(version, sizeof version)) { fprintf(stderr, "fapplay: empty file\n"); return 1; }
    if (strncmp(version, "2.", 2) != 0) { fprintf(stderr, "fapplay: version %s not supported\n", version); return 69; }
    /* header: name (one token here), frame rate, frame count */
    if (!token(name, sizeof name) || !token(tok, sizeof tok)) { fprintf(stderr, "fapplay: bad header\n"); return 1; }
    double rate = atof(tok);
    long nframes = integer("frame count");
    if (nframes < 0 || nframes > 10000000) { fprintf(stderr, "fapplay: frame count %ld\n", nframes); return 1; }
    FILE *out = fopen(argv[2], "w");
    if (!out) { perror(argv[2]); return 1; }
    fprintf(out, "2.1 %s %g %ld\n", name, rate, nframes);
    long value[NFAP] = {0}, vis[4] = {0}, expr[6] = {0};
    int held[NFAP] = {0};
    for (long f = 0; f < nframes; f++) {
        int mask[NFAP];
        for (int i = 0; i < NFAP; i++) {
            long m = integer("mask entry");
            if (m != 0 && m != 1) { fprintf(stderr, "fapplay: line %d: mask entry %ld\n", line_no, m); return 1; }
            mask[i] = (int)m;
        }
        long frame = integer("frame number");
        if (mask[0]) for (int i = 0; i < 4; i++) vis[i] = integer("viseme field");
        if (mask[1]) for (int i = 0; i < 6; i++) expr[i] = integer("expression field");
        for (int i = 2; i < NFAP; i++)
            if (mask[i]) { value[i] = integer("FAP value"); held[i] = 1; }
        if (mask[0]) held[0] = 1;
        if (mask[1]) held[1] = 1;
        for (int i = 0; i < NFAP; i++) fprintf(out, "%d%c", held[i], i + 1 < NFAP ? ' ' : '\n');
        fprintf(out, "%ld", frame);
        if (held[0]) for (int i = 0; i < 4; i++) fprintf(out, " %ld", vis[i]);
        if (held[1]) for (int i = 0; i < 6; i++) fprintf(out, " %ld", expr[i]);
        for (int i = 2; i < NFAP; i++) if (held[i]) fprintf(out, " %ld", value[i]);
        fputc('\n', out);
    }
    if (fclose(out) != 0) { perror(argv[2]); return 1; }
    return 0;
}
