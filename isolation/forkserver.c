/* The fork server in C: the protocol and behaviour of forkserver.py (see its docstring), without
 * an interpreter between the harness and each decoder. The harness compiles it on first use
 * (isolation/forkserver_build.py) and falls back to forkserver.py when no C compiler is at hand.
 *
 *   fbaconf-forkserver --fds OUT ERR [OUT ERR ...] [--reap-namespace]
 *
 * Request (after a 4-byte big-endian length): NUL-terminated fields
 *   nonce, slot, as, fsize, cpu, timeout, rss_mb, cwd, argc, argv..., envc, env...
 * Reply (after a 4-byte big-endian length), ASCII:
 *   nonce status utime stime maxrss_kb elapsed timed_out mem_hit exec_errno
 * The first message is "ready", once the server runs inside its sandbox.
 *
 * The reply channel is the server's stdout, which no decoder inherits; the server makes itself
 * non-dumpable, so a decoder (without CAP_SYS_PTRACE: the sandbox drops every capability)
 * cannot open it, nor the request pipe, through /proc/<ppid>/fd. Each reply echoes its
 * request's nonce, which the client checks: bytes a decoder got into the channel anyway are a
 * garbled or forged reply, the decoder's finding, never an ending moved onto another input.
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define MAX_SLOTS 64
#define MAX_FIELDS 8192
#define NOFILE 1024 /* descriptors per decoder process (isolation/seccomp.py) */
#define MAX_NONCE 64

static int slots[MAX_SLOTS][2] = {{3, 4}};
static int nslots = 1;

static int read_exact(char *buf, size_t n) {
    size_t got = 0;
    while (got < n) {
        ssize_t r = read(0, buf + got, n - got);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) return -1;
        got += (size_t)r;
    }
    return 0;
}

static void write_all(int fd, const char *buf, size_t n) {
    while (n > 0) {
        ssize_t w = write(fd, buf, n);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) _exit(1); /* the harness is gone */
        buf += w;
        n -= (size_t)w;
    }
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

/* The limit as the one-shot launcher sets it: capped by the hard limit, which it lowers to the
 * value only when it was unlimited; 0 = not set. */
static void set_limit(int which, long long value) {
    struct rlimit rl;
    if (value <= 0 || getrlimit(which, &rl) != 0) return;
    rlim_t v = (rlim_t)value;
    if (rl.rlim_max != RLIM_INFINITY && v > rl.rlim_max) v = rl.rlim_max;
    rl.rlim_cur = v;
    if (rl.rlim_max == RLIM_INFINITY) rl.rlim_max = v;
    setrlimit(which, &rl);
}

/* PATH search in the decoder's own environment (its PATH, else /usr/bin:/bin). */
static const char *find_program(const char *prog, char **env, char *buf, size_t bufsize) {
    if (strchr(prog, '/')) return prog;
    const char *path = "/usr/bin:/bin";
    for (char **e = env; *e; e++)
        if (strncmp(*e, "PATH=", 5) == 0) path = *e + 5;
    while (*path) {
        const char *end = strchr(path, ':');
        size_t len = end ? (size_t)(end - path) : strlen(path);
        int n = len ? snprintf(buf, bufsize, "%.*s/%s", (int)len, path, prog)
                    : snprintf(buf, bufsize, "./%s", prog);
        struct stat st;
        if (n > 0 && (size_t)n < bufsize && access(buf, X_OK) == 0 && stat(buf, &st) == 0 && !S_ISDIR(st.st_mode))
            return buf;
        if (!end) break;
        path = end + 1;
    }
    return prog;
}

/* The child's exec error, written by the vfork()ed child into the server's memory (which it
 * shares until it execs or exits): the server's own knowledge that the exec failed. */
static volatile int exec_errno;

/* In the vfork()ed child (the server waits until it execs or exits): system calls only. */
static void child(const char *prog, char **argv, char **env, const char *cwd, int out_fd, int err_fd,
                  long long as, long long fsize, long long cpu) {
    setsid();
    int null = open("/dev/null", O_RDONLY);
    if (null >= 0 && null != 0) dup2(null, 0);
    dup2(out_fd, 1);
    dup2(err_fd, 2);
#ifdef SYS_close_range
    if (syscall(SYS_close_range, 3, ~0U, 0) != 0)
#endif
        for (int fd = 3; fd < 4096; fd++) close(fd);
    int sigs[] = {SIGPIPE, SIGXCPU, SIGXFSZ, SIGINT, SIGTERM};
    for (size_t i = 0; i < sizeof sigs / sizeof sigs[0]; i++) signal(sigs[i], SIG_DFL);
    sigset_t none;
    sigemptyset(&none);
    sigprocmask(SIG_SETMASK, &none, NULL);
    set_limit(RLIMIT_AS, as);
    set_limit(RLIMIT_FSIZE, fsize);
    set_limit(RLIMIT_CPU, cpu);
    set_limit(RLIMIT_NOFILE, NOFILE);
    struct rlimit zero = {0, 0};
    setrlimit(RLIMIT_CORE, &zero);
    if (chdir(cwd) == 0) execve(prog, argv, env);
    exec_errno = errno ? errno : ENOEXEC;
    dprintf(2, "fbaconf-limit: cannot execute '%s': %s\n", argv[0], strerror(errno));
    _exit(127);
}

static double rss_one(pid_t pid) {
    char path[64], text[256];
    snprintf(path, sizeof path, "/proc/%d/statm", (int)pid);
    int fd = open(path, O_RDONLY);
    if (fd < 0) return 0.0;
    ssize_t n = read(fd, text, sizeof text - 1);
    close(fd);
    if (n <= 0) return 0.0;
    text[n] = 0;
    long size, resident;
    if (sscanf(text, "%ld %ld", &size, &resident) != 2) return 0.0;
    return (double)resident * (double)sysconf(_SC_PAGESIZE) / 1048576.0;
}

/* The decoder's resident memory: inside the sandbox's own PID namespace (reap), every process
 * but its init and this server — the decoder's whole tree; else the decoder's own. */
static double rss_mb(pid_t pid, int reap) {
    if (!reap) return rss_one(pid);
    double total = 0.0;
    DIR *d = opendir("/proc");
    if (!d) return rss_one(pid);
    struct dirent *e;
    while ((e = readdir(d))) {
        char *end;
        long p = strtol(e->d_name, &end, 10);
        if (*end || p <= 1 || p == getpid()) continue;
        total += rss_one((pid_t)p);
    }
    closedir(d);
    return total;
}

/* Inside the sandbox's own PID namespace: kill every process but its init and this server. */
static void reap_namespace(void) {
    pid_t keep[3] = {1, getpid(), getppid()};
    for (int round = 0; round < 50; round++) {
        int others = 0;
        DIR *d = opendir("/proc");
        if (!d) return;
        struct dirent *e;
        while ((e = readdir(d))) {
            char *end;
            long pid = strtol(e->d_name, &end, 10);
            if (*end || pid <= 0 || pid == keep[0] || pid == keep[1] || pid == keep[2]) continue;
            others++;
            kill((pid_t)pid, SIGKILL);
        }
        closedir(d);
        if (!others) return;
        struct timespec ms = {0, 1000000};
        nanosleep(&ms, NULL);
        while (waitpid(-1, NULL, WNOHANG) > 0) {}
    }
}

static void reply(const char *text) {
    uint32_t n = (uint32_t)strlen(text);
    unsigned char head[4] = {n >> 24, (n >> 16) & 255, (n >> 8) & 255, n & 255};
    char buf[512];
    memcpy(buf, head, 4);
    memcpy(buf + 4, text, n);
    write_all(1, buf, n + 4);
}

static int serve(char *msg, uint32_t len, int reap) {
    char *fields[MAX_FIELDS];
    int nf = 0;
    if (len == 0 || msg[len - 1] != 0) return -1;
    for (char *p = msg; p < msg + len && nf < MAX_FIELDS; p += strlen(p) + 1) fields[nf++] = p;
    if (nf < 10 || strlen(fields[0]) > MAX_NONCE) return -1;
    const char *nonce = fields[0];
    nf--;
    for (int i = 0; i < nf; i++) fields[i] = fields[i + 1];
    int slot = atoi(fields[0]);
    long long as = atoll(fields[1]), fsize = atoll(fields[2]), cpu = atoll(fields[3]);
    double timeout = atof(fields[4]), rss_limit = atof(fields[5]);
    const char *cwd = fields[6];
    int argc = atoi(fields[7]);
    if (slot < 0 || slot >= nslots || argc < 1 || 8 + argc >= nf) return -1;
    int envc = atoi(fields[8 + argc]);
    if (envc < 0 || 9 + argc + envc > nf) return -1;
    char *argv[argc + 1], *env[envc + 1];
    for (int i = 0; i < argc; i++) argv[i] = fields[8 + i];
    argv[argc] = NULL;
    for (int i = 0; i < envc; i++) env[i] = fields[9 + argc + i];
    env[envc] = NULL;
    int out_fd = slots[slot][0], err_fd = slots[slot][1];
    for (int i = 0; i < 2; i++) {
        int fd = i ? err_fd : out_fd;
        if (ftruncate(fd, 0) != 0 || lseek(fd, 0, SEEK_SET) < 0) return -1;
    }
    char buf[4096];
    const char *prog = find_program(argv[0], env, buf, sizeof buf);
    double t0 = now();
    exec_errno = 0;
    pid_t pid = vfork();
    if (pid == 0) child(prog, argv, env, cwd, out_fd, err_fd, as, fsize, cpu);
    if (pid < 0 || exec_errno) {
        int why = pid < 0 ? errno : exec_errno;
        if (pid < 0) dprintf(err_fd, "fbaconf-limit: cannot execute '%s': %s\n", argv[0], strerror(why));
        else while (waitpid(pid, NULL, 0) < 0 && errno == EINTR) {}
        char text[256];
        snprintf(text, sizeof text, "%s %d 0 0 0 %.6f 0 0 %d", nonce, 127 << 8, now() - t0, why ? why : ENOEXEC);
        reply(text);
        return 0;
    }
    int pidfd = (int)syscall(SYS_pidfd_open, pid, 0);
    double deadline = t0 + timeout;
    int timed_out = 0, mem_hit = 0, status = 0;
    struct rusage ru;
    memset(&ru, 0, sizeof ru);
    for (;;) {
        pid_t w = wait4(pid, &status, WNOHANG, &ru);
        if (w == pid) break;
        if (w < 0 && errno != EINTR) break;
        double left = deadline - now();
        if (left <= 0) timed_out = 1;
        else if (rss_limit > 0 && rss_mb(pid, reap) > rss_limit) mem_hit = 1;
        if (timed_out || mem_hit) {
            if (killpg(pid, SIGKILL) != 0) kill(pid, SIGKILL);
            while (wait4(pid, &status, 0, &ru) < 0 && errno == EINTR) {}
            break;
        }
        double wait = rss_limit > 0 && left > 0.005 ? 0.005 : left;
        if (pidfd >= 0) {
            struct pollfd p = {pidfd, POLLIN, 0};
            struct timespec ts = {(time_t)wait, (long)((wait - (double)(time_t)wait) * 1e9)};
            ppoll(&p, 1, &ts, NULL);
        } else {
            struct timespec ts = {0, 500000};
            nanosleep(&ts, NULL);
        }
    }
    double elapsed = now() - t0;
    if (pidfd >= 0) close(pidfd);
    killpg(pid, SIGKILL); /* what the decoder left behind in its session */
    if (reap) reap_namespace();
    char text[256];
    snprintf(text, sizeof text, "%s %d %.6f %.6f %ld %.6f %d %d 0", nonce, status,
             (double)ru.ru_utime.tv_sec + (double)ru.ru_utime.tv_usec * 1e-6,
             (double)ru.ru_stime.tv_sec + (double)ru.ru_stime.tv_usec * 1e-6,
             ru.ru_maxrss, elapsed, timed_out, mem_hit);
    reply(text);
    return 0;
}

int main(int argc, char **argv) {
    int reap = 0;
    for (int i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--reap-namespace") == 0) reap = 1;
        if (strcmp(argv[i], "--fds") == 0) {
            int n = 0;
            while (i + 1 < argc && argv[i + 1][0] >= '0' && argv[i + 1][0] <= '9' && n < 2 * MAX_SLOTS) {
                slots[n / 2][n % 2] = atoi(argv[++i]);
                n++;
            }
            nslots = n / 2;
        }
    }
    for (int s = 0; s < nslots; s++)
        for (int k = 0; k < 2; k++) fcntl(slots[s][k], F_SETFD, FD_CLOEXEC); /* children get one pair as 1, 2 */
    struct rlimit zero = {0, 0};
    setrlimit(RLIMIT_CORE, &zero);
    prctl(PR_SET_DUMPABLE, 0, 0, 0, 0); /* its descriptors and memory closed to /proc (see the top) */
    signal(SIGXCPU, SIG_IGN); /* the server's own CPU time may pass a child's limit */
    signal(SIGPIPE, SIG_DFL);
    reply("ready"); /* the hello: started inside the sandbox */
    for (;;) {
        unsigned char head[4];
        if (read_exact((char *)head, 4) != 0) return 0;
        uint32_t len = ((uint32_t)head[0] << 24) | ((uint32_t)head[1] << 16) | ((uint32_t)head[2] << 8) | head[3];
        if (len > (64u << 20)) return 2;
        char *msg = malloc(len ? len : 1);
        if (!msg || read_exact(msg, len) != 0) return 0;
        if (serve(msg, len, reap) != 0) {
            fprintf(stderr, "fbaconf-forkserver: malformed request\n");
            return 2;
        }
        free(msg);
    }
}
