/* Host build of the bridge firmware: the portable core served on a pseudo-terminal (--pty,
 * whose path is printed on the first stdout line) or on stdin/stdout.
 *
 * The timer is not real: every compare value the core sets is written to the trace file
 * (--trace FILE) as "<t_ms> ccr <ch> <value> <cause>", the cause being boot, command,
 * watchdog or exit.
 * SIGTERM, SIGINT and end of input put every channel at neutral before exiting.
 *
 * Output never blocks: the output descriptor is non-blocking, and a reply the peer has no
 * room for is dropped (like a UART: what nobody reads is lost). A peer that stops reading
 * therefore cannot stop the loop, so the watchdog and the signals keep working. */
#define _XOPEN_SOURCE 600

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "../bridge_core.h"
#include "../bridge_rig.h"

typedef struct {
    int out_fd;
    FILE *trace;
    const char *cause;  /* what the core is doing when it sets a compare value */
} host_io;

static volatile sig_atomic_t quit;

static void on_signal(int sig)
{
    (void)sig;
    quit = 1;
}

static uint32_t now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint32_t)((uint64_t)ts.tv_sec * 1000u + (uint64_t)ts.tv_nsec / 1000000u);
}

static void set_compare(void *ctx, uint8_t ch, uint32_t ccr)
{
    host_io *io = ctx;
    if (io->trace != NULL) {
        fprintf(io->trace, "%lu ccr %u %lu %s\n", (unsigned long)now_ms(), (unsigned)ch,
                (unsigned long)ccr, io->cause);
        fflush(io->trace);
    }
}

static void write_bytes(void *ctx, const char *bytes, size_t n)
{
    host_io *io = ctx;
    while (n > 0u && !quit) {
        ssize_t done = write(io->out_fd, bytes, n);
        if (done < 0) {
            if (errno == EINTR) {
                continue;
            }
            return;  /* EAGAIN (the peer does not read) or gone: like a UART, what nobody
                        reads is lost */
        }
        bytes += done;
        n -= (size_t)done;
    }
}

/* Make `fd` non-blocking; its flags before, or -1. */
static int nonblocking(int fd)
{
    int flags = fcntl(fd, F_GETFL);
    if (flags < 0 || fcntl(fd, F_SETFL, flags | O_NONBLOCK) != 0) {
        return -1;
    }
    return flags;
}

/* A stand-in sample (no motor here), so the TEL line format can be exercised. */
static bridge *telemetry_source;

static int read_telemetry(void *ctx, bridge_telemetry *out)
{
    (void)ctx;
    out->speed_drpm = (int32_t)telemetry_source->ccr[0] * 10;
    out->current_ma = (int32_t)telemetry_source->ccr[0];
    out->voltage_cv = 1200;
    return 1;
}

static int open_pty(int *slave_out)
{
    struct termios tio;
    int master = posix_openpt(O_RDWR | O_NOCTTY);
    int slave;
    if (master < 0 || grantpt(master) != 0 || unlockpt(master) != 0) {
        return -1;
    }
    /* Keep a slave fd open: the pty then survives hosts that open and close it. */
    slave = open(ptsname(master), O_RDWR | O_NOCTTY);
    if (slave < 0 || tcgetattr(slave, &tio) != 0) {
        return -1;
    }
    tio.c_iflag &= ~(tcflag_t)(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON);
    tio.c_oflag &= ~(tcflag_t)OPOST;
    tio.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    tio.c_cflag &= ~(tcflag_t)(CSIZE | PARENB);
    tio.c_cflag |= CS8;
    tio.c_cc[VMIN] = 1;
    tio.c_cc[VTIME] = 0;
    if (tcsetattr(slave, TCSANOW, &tio) != 0) {
        return -1;
    }
    *slave_out = slave;
    return master;
}

static int parse_u32(const char *text, uint32_t *out)
{
    char *end;
    unsigned long v;
    errno = 0;
    v = strtoul(text, &end, 10);
    if (errno != 0 || end == text || *end != '\0' || text[0] == '-' || v > 0xFFFFFFFFul) {
        return 0;
    }
    *out = (uint32_t)v;
    return 1;
}

static int usage(void)
{
    fprintf(stderr, "usage: bridge_host [--pty] [--trace FILE] [--clock-hz N] [--psc N] [--arr N]\n"
                    "                   [--neutral N] [--watchdog-ms N] [--telemetry-ms N] [--channels N]\n"
                    "                   [--ccr-min N] [--ccr-max N]\n");
    return 2;
}

int main(int argc, char **argv)
{
    bridge_config cfg = {BRIDGE_TIMER_CLOCK_HZ, BRIDGE_PSC, BRIDGE_ARR, BRIDGE_NEUTRAL_CCR,
                         BRIDGE_WATCHDOG_MS, BRIDGE_TELEMETRY_MS, BRIDGE_CHANNELS,
                         BRIDGE_CCR_MIN, BRIDGE_CCR_MAX};
    static bridge b;
    host_io io = {1, NULL, "boot"};
    bridge_hooks hooks = {set_compare, write_bytes, read_telemetry, NULL};
    uint32_t channels = cfg.channels, ccr_max = UINT32_MAX, arr_given = 0;
    struct sigaction sa;
    int use_pty = 0, in_fd = 0, slave = -1, out_flags, i;

    for (i = 1; i < argc; i++) {
        const char *opt = argv[i];
        uint32_t *target = NULL;
        if (strcmp(opt, "--pty") == 0) {
            use_pty = 1;
            continue;
        }
        if (i + 1 >= argc) {
            return usage();
        }
        if (strcmp(opt, "--trace") == 0) {
            io.trace = fopen(argv[++i], "w");
            if (io.trace == NULL) {
                fprintf(stderr, "bridge_host: cannot write %s: %s\n", argv[i], strerror(errno));
                return 2;
            }
            continue;
        }
        if (strcmp(opt, "--clock-hz") == 0) target = &cfg.timer_clock_hz;
        else if (strcmp(opt, "--psc") == 0) target = &cfg.psc;
        else if (strcmp(opt, "--arr") == 0) {
            target = &cfg.arr;
            arr_given = 1;
        }
        else if (strcmp(opt, "--ccr-min") == 0) target = &cfg.ccr_min;
        else if (strcmp(opt, "--ccr-max") == 0) target = &ccr_max;
        else if (strcmp(opt, "--neutral") == 0) target = &cfg.neutral_ccr;
        else if (strcmp(opt, "--watchdog-ms") == 0) target = &cfg.watchdog_ms;
        else if (strcmp(opt, "--telemetry-ms") == 0) target = &cfg.telemetry_ms;
        else if (strcmp(opt, "--channels") == 0) target = &channels;
        if (target == NULL || !parse_u32(argv[++i], target)) {
            return usage();
        }
    }
    cfg.channels = (uint8_t)(channels > 255u ? 255u : channels);
    if (ccr_max != UINT32_MAX || arr_given) {
        cfg.ccr_max = ccr_max != UINT32_MAX ? ccr_max : cfg.arr;  /* default: the whole timer */
    }
    if (cfg.psc > 65535u) {
        fprintf(stderr, "bridge_host: --psc must be at most 65535\n");
        return 2;
    }
    hooks.ctx = &io;
    telemetry_source = &b;
    if (use_pty) {
        in_fd = io.out_fd = open_pty(&slave);
        if (in_fd < 0) {
            fprintf(stderr, "bridge_host: cannot open a pseudo-terminal: %s\n", strerror(errno));
            return 1;
        }
        printf("%s\n", ptsname(in_fd));
        fflush(stdout);
    }
    out_flags = nonblocking(io.out_fd);
    if (out_flags < 0) {
        fprintf(stderr, "bridge_host: cannot make the output non-blocking: %s\n", strerror(errno));
        return 1;
    }
    if (bridge_init(&b, &cfg, &hooks, now_ms()) != 0) {
        fprintf(stderr, "bridge_host: inconsistent timer settings (need arr >= 1, "
                        "ccr-min <= neutral <= ccr-max <= arr, channels 1..%u)\n", BRIDGE_MAX_CHANNELS);
        fcntl(io.out_fd, F_SETFL, out_flags);
        return 2;
    }
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    while (!quit) {
        struct pollfd pfd;
        uint8_t buf[256];
        pfd.fd = in_fd;
        pfd.events = POLLIN;
        pfd.revents = 0;
        if (poll(&pfd, 1, 1) > 0) {
            ssize_t n = read(in_fd, buf, sizeof buf);
            if (n == 0 || (n < 0 && errno != EINTR && errno != EAGAIN)) {
                break;  /* end of input, or the pty is gone */
            }
            if (n > 0) {
                io.cause = "command";
                bridge_feed(&b, buf, (size_t)n, now_ms());
            }
        }
        io.cause = "watchdog";  /* the only compare values a tick sets */
        bridge_tick(&b, now_ms());
    }
    io.cause = "exit";
    bridge_all_neutral(&b);
    fcntl(io.out_fd, F_SETFL, out_flags);  /* stdout may be shared: give it back as it was */
    if (slave >= 0) {
        close(slave);
    }
    return 0;
}
