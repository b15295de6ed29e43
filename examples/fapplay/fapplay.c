/* fapplay: a tiny "player" for the .fap text form, written as the worked adapter example of
 * docs/harness.md. It reads IN.fap, keeps the FAP state the way a player does (a FAP not
 * sent in a frame keeps its last value), and writes OUT.fap with every FAP it holds.
 *
 *   cc -O2 -o fapplay fapplay.c && ./fapplay IN.fap OUT.fap
 *
 * Exit codes: 0 done, 1 unreadable input (message on stderr), 69 not supported.
 */
#include <ctype.h>
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define NFAP 68

static FILE *in;
static int line_no = 1;
static char pushed[2][256];
static int pushed_line[2], npushed = 0;  /* tokens given back (a stack) and their lines */

/* next character, with every line end read as '\n': LF, CRLF and a lone CR (old Mac files) */
static int nextc(void) {
    int c = fgetc(in);
    if (c == '\r') {
        int d = fgetc(in);
        if (d != '\n' && d != EOF) ungetc(d, in);
        return '\n';
    }
    return c;
}

/* next whitespace-separated token and the line it starts on, skipping '#' comments;
 * returns 0 at end of file */
static int token(char *buf, size_t n, int *at) {
    int c;
    size_t k = 0;
    if (npushed) {
        npushed--;
        snprintf(buf, n, "%s", pushed[npushed]);
        if (at) *at = pushed_line[npushed];
        return 1;
    }
    for (;;) {
        c = nextc();
        if (c == EOF) return 0;
        if (c == '\n') line_no++;
        if (c == '#') {
            while ((c = nextc()) != EOF && c != '\n') {}
            if (c == '\n') line_no++;
            continue;
        }
        if (!isspace(c)) break;
    }
    if (at) *at = line_no;
    do {
        if (k + 1 < n) buf[k++] = (char)c;
        c = nextc();
    } while (c != EOF && !isspace(c) && c != '#');
    if (c == '\n') line_no++;
    if (c == '#') ungetc(c, in);
    buf[k] = 0;
    return 1;
}

static void give_back(const char *tok, int at) {  /* at most two are ever given back */
    snprintf(pushed[npushed], sizeof pushed[npushed], "%s", tok);
    pushed_line[npushed++] = at;
}

static long integer(const char *what, int *at) {
    char buf[64], *end;
    if (!token(buf, sizeof buf, at)) {
        fprintf(stderr, "fapplay: line %d: end of file, expected %s\n", line_no, what);
        exit(1);
    }
    errno = 0;
    long v = strtol(buf, &end, 10);
    if (*end || end == buf) {
        fprintf(stderr, "fapplay: line %d: %s is not an integer: %s\n", line_no, what, buf);
        exit(1);
    }
    if (errno == ERANGE || v < INT32_MIN || v > INT32_MAX) {  /* values and frame numbers are int32 */
        fprintf(stderr, "fapplay: line %d: %s is outside the int32 range: %s\n", line_no, what, buf);
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
    /* header: the first line with tokens: version, name (any words), frame rate, frame count */
    char head[16][256], tok[256];
    int nh = 0, first, at;
    if (!token(head[0], sizeof head[0], &first)) { fprintf(stderr, "fapplay: empty file\n"); return 1; }
    for (nh = 1; nh < 16 && token(tok, sizeof tok, &at); nh++) {
        if (at != first) { give_back(tok, at); break; }
        snprintf(head[nh], sizeof head[nh], "%s", tok);
    }
    if (nh < 3) { fprintf(stderr, "fapplay: bad header\n"); return 1; }
    if (strncmp(head[0], "2.", 2) != 0) { fprintf(stderr, "fapplay: version %s not supported\n", head[0]); return 69; }
    double rate = atof(head[nh - 2]);
    if (!(rate > 0)) { fprintf(stderr, "fapplay: bad frame rate %s\n", head[nh - 2]); return 1; }
    FILE *out = fopen(argv[2], "w");
    if (!out) { perror(argv[2]); return 1; }
    fprintf(out, "2.1 fapplay %.17g ", rate);
    long count_at = ftell(out), count = 0;
    fprintf(out, "%10ld\n", 0L);   /* the frame count, rewritten at the end */
    long value[NFAP] = {0}, vis[4] = {0}, expr[6] = {0};
    int held[NFAP] = {0};
    while (token(tok, sizeof tok, &at)) {  /* frames until the end of the file */
        give_back(tok, at);
        int mask[NFAP], start = 0;
        for (int i = 0; i < NFAP; i++) {
            int l;
            long m = integer("mask entry", &l);
            if (i == 0) start = l;
            if (m != 0 && m != 1) { fprintf(stderr, "fapplay: line %d: mask entry %ld\n", line_no, m); return 1; }
            mask[i] = (int)m;
        }
        /* Greta writes 69 mask entries: a 69th "0" closing the mask's own line is dropped */
        if (token(tok, sizeof tok, &at)) {
            char next[256];
            int at2 = 0;
            int last_on_line = at == start && strcmp(tok, "0") == 0 &&
                               (!token(next, sizeof next, &at2) || at2 != start);
            if (at2) give_back(next, at2);
            if (!last_on_line) give_back(tok, at);  /* not Greta's: it was the frame number */
        }
        long frame = integer("frame number", NULL);
        if (mask[0]) for (int i = 0; i < 4; i++) vis[i] = integer("viseme field", NULL);
        if (mask[1]) for (int i = 0; i < 6; i++) expr[i] = integer("expression field", NULL);
        for (int i = 2; i < NFAP; i++)
            if (mask[i]) { value[i] = integer("FAP value", NULL); held[i] = 1; }
        if (mask[0]) held[0] = 1;
        if (mask[1]) held[1] = 1;
        for (int i = 0; i < NFAP; i++) fprintf(out, "%d%c", held[i], i + 1 < NFAP ? ' ' : '\n');
        fprintf(out, "%ld", frame);
        if (held[0]) for (int i = 0; i < 4; i++) fprintf(out, " %ld", vis[i]);
        if (held[1]) for (int i = 0; i < 6; i++) fprintf(out, " %ld", expr[i]);
        for (int i = 2; i < NFAP; i++) if (held[i]) fprintf(out, " %ld", value[i]);
        fputc('\n', out);
        count++;
    }
    fseek(out, count_at, SEEK_SET);
    fprintf(out, "%10ld", count);
    if (fclose(out) != 0) { perror(argv[2]); return 1; }
    return 0;
}
