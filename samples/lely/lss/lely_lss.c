/*
 * lely_lss.c - one Lely CANopen device with LSS (CiA 305) on the hub bus of
 * samples/canopennode/hub.py, for nmtcheck's Lely LSS recordings (README.md here).
 *
 * The device is lely-core's C stack: a co_dev_t from lss.eds (../slave.eds with
 * LSS_Supported = 1) and its NMT service (co_nmt_t), whose LSS service (src/co/lss.c)
 * is an LSS master when the NMT startup value 1F80h has bit 0 set and an LSS slave
 * otherwise. Its CAN network interface (can_net_t) sends each frame to the hub as one
 * datagram and receives the hub's datagrams; the hub timestamps and logs every frame.
 *
 * usage: lely_lss --hub DIR --name NAME --node N|255 [--identity V:P:R:S (hex)]
 *                 [--master --script "CMD;CMD;..."]
 *   --master  NMT and LSS master (1F80h = 1): at its communication reset Lely calls the
 *             LSS request function (co_nmt_set_lss_req), which runs the script with
 *             Lely's LSS master requests, one after the other, each to its indication;
 *             then co_nmt_lss_con() lets the master boot (boot-up, NMT reset of all).
 *     select V:P:R:S | node N | store | waiting | fastscan | inquire_node
 * Ground truth on stderr (the hub's .events file), CLOCK_REALTIME stamps: each request
 * and what Lely's indication function reported (the cs received, or 0 on timeout; the
 * error code; the identity a fastscan found), and each device's NMT state changes.
 *
 * Part of nmtcheck (MIT). It contains no Lely code; it includes the headers of, and
 * links against, an installed lely-core (Apache-2.0).
 */
#include <lely/can/msg.h>
#include <lely/can/net.h>
#include <lely/co/dcf.h>
#include <lely/co/dev.h>
#include <lely/co/lss.h>
#include <lely/co/nmt.h>

#include <errno.h>
#include <poll.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

/* the hub's wire format (samples/canopennode/CO_driver_target.h hub_frame_t) */
typedef struct {
    uint8_t type, rtr, dlc, pad;
    uint32_t id;
    uint8_t data[8];
} hub_frame_t;

static int hubFd = -1;
static const char* devName = "lely";
static char script[1024] = "";
static char* cmdNext = script;
static co_nmt_t* nmt = NULL;

static void
logf_(const char* fmt, ...) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    char line[512];
    int n = snprintf(line, sizeof(line), "# %ld.%06ld %s: ", (long)ts.tv_sec, ts.tv_nsec / 1000, devName);
    va_list ap;
    va_start(ap, fmt);
    n += vsnprintf(line + n, sizeof(line) - (size_t)n - 1, fmt, ap);
    va_end(ap);
    if (n > (int)sizeof(line) - 2) {
        n = (int)sizeof(line) - 2;
    }
    line[n++] = '\n';
    (void)!write(2, line, (size_t)n);
}

static int
send_to_hub(const struct can_msg* msg, void* data) {
    (void)data;
    hub_frame_t f;
    memset(&f, 0, sizeof(f));
    f.type = 'F';
    f.id = msg->id & 0x7FF;
    f.rtr = (msg->flags & CAN_FLAG_RTR) ? 1 : 0;
    f.dlc = msg->len;
    memcpy(f.data, msg->data, msg->len > 8 ? 8 : msg->len);
    return send(hubFd, &f, sizeof(f), 0) == (ssize_t)sizeof(f) ? 0 : -1;
}

static void next_request(co_lss_t* lss);

static void
on_cs(co_lss_t* lss, co_unsigned8_t cs, void* data) {
    logf_("master: %s -> cs %02Xh%s", (const char*)data, cs, cs ? "" : " (timeout)");
    next_request(lss);
}

static void
on_err(co_lss_t* lss, co_unsigned8_t cs, co_unsigned8_t err, co_unsigned8_t spec, void* data) {
    logf_("master: %s -> cs %02Xh error %u spec %u%s", (const char*)data, cs, err, spec, cs ? "" : " (timeout)");
    next_request(lss);
}

static void
on_nid(co_lss_t* lss, co_unsigned8_t cs, co_unsigned8_t id, void* data) {
    logf_("master: %s -> cs %02Xh node-ID %u%s", (const char*)data, cs, id, cs ? "" : " (timeout)");
    next_request(lss);
}

static void
on_scan(co_lss_t* lss, co_unsigned8_t cs, const struct co_id* id, void* data) {
    if (id != NULL) {
        logf_("master: %s -> cs %02Xh found %08X:%08X:%08X:%08X", (const char*)data, cs, (unsigned)id->vendor_id,
              (unsigned)id->product_code, (unsigned)id->revision, (unsigned)id->serial_nr);
    } else {
        logf_("master: %s -> cs %02Xh, no slave found", (const char*)data, cs);
    }
    next_request(lss);
}

static char cmd[128];

/* the script's next request; at its end, let the NMT master go on booting */
static void
next_request(co_lss_t* lss) {
    while (*cmdNext) {
        char* end = strchr(cmdNext, ';');
        size_t len = end ? (size_t)(end - cmdNext) : strlen(cmdNext);
        if (len >= sizeof(cmd)) {
            len = sizeof(cmd) - 1;
        }
        memcpy(cmd, cmdNext, len);
        cmd[len] = 0;
        cmdNext = end ? end + 1 : cmdNext + strlen(cmdNext);
        unsigned v[4] = {0, 0, 0, 0};
        int rc = -1;
        if (sscanf(cmd, "select %x:%x:%x:%x", &v[0], &v[1], &v[2], &v[3]) == 4) {
            struct co_id id = {4, v[0], v[1], v[2], v[3]};
            rc = co_lss_switch_sel_req(lss, &id, on_cs, cmd);
        } else if (sscanf(cmd, "node %u", &v[0]) == 1) {
            rc = co_lss_set_id_req(lss, (co_unsigned8_t)v[0], on_err, cmd);
        } else if (!strcmp(cmd, "store")) {
            rc = co_lss_store_req(lss, on_err, cmd);
        } else if (!strcmp(cmd, "inquire_node")) {
            rc = co_lss_get_id_req(lss, on_nid, cmd);
        } else if (!strcmp(cmd, "fastscan")) {
            struct co_id id = {4, 0, 0, 0, 0}, mask = {4, 0, 0, 0, 0};
            rc = co_lss_fastscan_req(lss, &id, &mask, on_scan, cmd);
        } else if (!strcmp(cmd, "waiting")) {
            rc = co_lss_switch_req(lss, 0);
            logf_("master: %s -> %d (unconfirmed)", cmd, rc);
            continue;
        } else {
            logf_("master: unknown command '%s'", cmd);
            continue;
        }
        if (rc == 0) {
            return; /* its indication function goes on */
        }
        logf_("master: %s -> request refused (%d)", cmd, rc);
    }
    logf_("master: LSS done, co_nmt_lss_con()");
    co_nmt_lss_con(nmt);
}

static void
on_lss_req(co_nmt_t* n, co_lss_t* lss, void* data) {
    (void)n;
    (void)data;
    logf_("master: LSS request function called (communication reset), timeout %d ms", co_lss_get_timeout(lss));
    next_request(lss);
}

static void
on_state(co_nmt_t* n, co_unsigned8_t id, co_unsigned8_t st, void* data) {
    (void)data;
    logf_("NMT state of node %u: %02Xh", id, st);
    co_nmt_on_st(n, id, st);
}

static void
on_cs_ind(co_nmt_t* n, co_unsigned8_t cs, void* data) {
    (void)n;
    (void)data;
    logf_("NMT service %02Xh (node-ID %u)", cs, co_dev_get_id(co_nmt_get_dev(n)));
}

int
main(int argc, char** argv) {
    const char* hubDir = NULL;
    const char* eds = "lss.eds";
    int node = 0, master = 0;
    unsigned ident[4] = {0, 0, 0, 0};
    for (int i = 1; i < argc; i++) {
        const char* o = argv[i];
        const char* v = (i + 1 < argc) ? argv[i + 1] : "";
        if (!strcmp(o, "--hub")) { hubDir = v; i++; }
        else if (!strcmp(o, "--name")) { devName = v; i++; }
        else if (!strcmp(o, "--node")) { node = atoi(v); i++; }
        else if (!strcmp(o, "--eds")) { eds = v; i++; }
        else if (!strcmp(o, "--identity")) {
            if (sscanf(v, "%x:%x:%x:%x", &ident[0], &ident[1], &ident[2], &ident[3]) != 4) {
                fprintf(stderr, "--identity V:P:R:S (hex)\n");
                return 2;
            }
            i++;
        }
        else if (!strcmp(o, "--master")) { master = 1; }
        else if (!strcmp(o, "--script")) { strncpy(script, v, sizeof(script) - 1); i++; }
        else { fprintf(stderr, "unknown option %s\n", o); return 2; }
    }
    if (hubDir == NULL || !((node >= 1 && node <= 127) || node == 0xFF)) {
        fprintf(stderr, "usage: lely_lss --hub DIR --name NAME --node N|255 [options]\n");
        return 2;
    }
    struct sockaddr_un me = {.sun_family = AF_UNIX}, hub = {.sun_family = AF_UNIX};
    snprintf(me.sun_path, sizeof(me.sun_path), "%s/dev-%s.sock", hubDir, devName);
    snprintf(hub.sun_path, sizeof(hub.sun_path), "%s/hub.sock", hubDir);
    hubFd = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    unlink(me.sun_path);
    if (hubFd < 0 || bind(hubFd, (struct sockaddr*)&me, sizeof(me)) < 0
        || connect(hubFd, (struct sockaddr*)&hub, sizeof(hub)) < 0) {
        perror("hub socket");
        return 1;
    }
    hub_frame_t hello = {.type = 'H'};
    send(hubFd, &hello, sizeof(hello), 0);

    co_dev_t* dev = co_dev_create_from_dcf_file(eds);
    if (dev == NULL) {
        fprintf(stderr, "cannot load %s\n", eds);
        return 1;
    }
    co_dev_set_id(dev, (co_unsigned8_t)node);
    for (int k = 0; k < 4; k++) {
        co_dev_set_val_u32(dev, 0x1018, (co_unsigned8_t)(k + 1), ident[k]);
    }
    co_dev_set_val_u32(dev, 0x1F80, 0, master ? 0x00000001u : 0x00000004u);
    can_net_t* net = can_net_create();
    can_net_set_send_func(net, send_to_hub, NULL);
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    can_net_set_time(net, &now);
    nmt = co_nmt_create(net, dev);
    if (nmt == NULL) {
        fprintf(stderr, "co_nmt_create failed\n");
        return 1;
    }
    co_nmt_set_st_ind(nmt, on_state, NULL);
    co_nmt_set_cs_ind(nmt, on_cs_ind, NULL);
    if (master) {
        co_nmt_set_lss_req(nmt, on_lss_req, NULL);
    }
    logf_("power-on: node-ID %d, identity %X:%X:%X:%X, %s", node, ident[0], ident[1], ident[2], ident[3],
          master ? "NMT/LSS master" : "LSS slave");
    co_nmt_cs_ind(nmt, CO_NMT_CS_RESET_NODE);
    for (;;) {
        struct pollfd p = {.fd = hubFd, .events = POLLIN};
        poll(&p, 1, 1);
        hub_frame_t f;
        ssize_t n;
        while ((n = recv(hubFd, &f, sizeof(f), MSG_DONTWAIT)) == (ssize_t)sizeof(f)) {
            if (f.type != 'F') {
                continue;
            }
            struct can_msg msg = CAN_MSG_INIT;
            msg.id = f.id;
            msg.flags = f.rtr ? CAN_FLAG_RTR : 0;
            msg.len = f.dlc;
            memcpy(msg.data, f.data, 8);
            clock_gettime(CLOCK_MONOTONIC, &now);
            can_net_set_time(net, &now);
            can_net_recv(net, &msg);
        }
        clock_gettime(CLOCK_MONOTONIC, &now);
        can_net_set_time(net, &now);
    }
}
