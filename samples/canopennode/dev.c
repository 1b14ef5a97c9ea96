/*
 * One CANopenNode v4 device (slave or simple NMT master) on the hub bus of
 * hub.py. Written for nmtcheck's recordings (see README.md); links against an
 * unmodified CANopenNode source tree (CANopen.c and the 301 folder) plus our OD.c and
 * CO_driver.c.
 *
 * Main loop as in CANopenNode's example/main_blank.c and CANopenLinux: a
 * communication-reset loop around CO_CANinit/CO_CANopenInit/CO_CANopenInitPDO,
 * and a processing loop that calls CO_process, CO_process_SYNC,
 * CO_process_RPDO and CO_process_TPDO at least every 1 ms and right after
 * every received frame, with the measured time difference (CLOCK_MONOTONIC).
 * CO_RESET_APP (NMT reset node) re-executes the program: the device powers
 * up again with its power-on object dictionary. CO_RESET_COMM keeps the
 * object dictionary in RAM (CANopenNode behaviour).
 *
 * usage: dev --hub DIR --name NAME --node N [--hb MS] [--self-start] [--no-tpdo]
 *            [--master --slaves 2h,3h,4g [--reset-all] [--reset-delay MS] [--config-delay MS]]
 *
 *   --hb MS        power-on producer heartbeat time 1017h (default 1000)
 *   --self-start   CO_NMT_STARTUP_TO_OPERATIONAL (enter OPERATIONAL after boot-up)
 *   --no-tpdo      TPDO1 invalid at power-on
 *   --master       NMT master application (always self-starting, as
 *                  CANopenNode's example NMT_CONTROL); --slaves lists the
 *                  nodes it configures: h = heartbeat, g = node guarding
 *   --reset-all    once per program run, --reset-delay ms after the boot-up,
 *                  send NMT reset communication to all nodes (000#8200)
 *
 * Control commands from the hub (scenario driver), one text datagram each:
 *   nmt CS NODE | sdo_read NODE IDX SUB | sdo_write NODE IDX SUB LEN VALUE |
 *   emcy_set | emcy_clear | set1017 MS | config NODE | quit
 *
 * `config NODE` (master: configure and start that one
 * slave again, as at boot; for a slave that was power-cycled or reset), and
 * `--guard MS:F` (power-on 100Ch/100Dh, as stored parameters; use with --hb 0), and
 * `--sync-us US` (SYNC producer on COB-ID 80h with period US at power-on).
 */
#include <errno.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#include "CANopen.h"
#include "OD.h"

#define FIRST_HB_TIME        500
#define SDO_SRV_TIMEOUT_TIME 1000
#define SDO_CLI_TIMEOUT_TIME 500

static CO_t* CO = NULL;
static int hubFd = -1;
static const char* devName = "dev";
static int nodeId = 0;
static int hbPowerOn = 1000;
static int selfStart = 0, noTpdo = 0, isMaster = 0, resetAll = 0;
static int resetDelayMs = 100, configDelayMs = 50;
static unsigned guardPowerOn = 0, lifePowerOn = 0; /* power-on 100Ch/100Dh (--guard) */
static unsigned syncUs = 0; /* SYNC producer period (1006h, --sync-us), 0 = none */
static char slavesSpec[128] = "";
static int resetAllDone = 0; /* survives communication resets (RAM) */

static uint64_t
now_us(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000u + (uint64_t)ts.tv_nsec / 1000u;
}

static void
logf_(const char* fmt, ...) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    fprintf(stderr, "# %ld.%06ld %s: ", (long)ts.tv_sec, ts.tv_nsec / 1000, devName);
    va_list ap;
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
}

/* ---------------------------------------------------------------- jobs */
typedef enum { J_SDO_W, J_SDO_R, J_NMT, J_LOCAL_1016, J_GUARD } jobType_t;
typedef struct {
    jobType_t type;
    uint8_t node;
    uint16_t index;
    uint8_t sub;
    uint8_t len;
    uint32_t value;
} job_t;

#define MAXJOBS 64
static job_t jobs[MAXJOBS];
static int jobHead = 0, jobTail = 0;
static int jobActive = 0; /* SDO transfer in progress */

static void
job_add(jobType_t t, int node, int index, int sub, int len, uint32_t value) {
    if ((jobTail + 1) % MAXJOBS == jobHead) {
        logf_("job queue full");
        return;
    }
    job_t* j = &jobs[jobTail];
    j->type = t;
    j->node = (uint8_t)node;
    j->index = (uint16_t)index;
    j->sub = (uint8_t)sub;
    j->len = (uint8_t)len;
    j->value = value;
    jobTail = (jobTail + 1) % MAXJOBS;
}

static void
jobs_clear(void) {
    jobHead = jobTail = 0;
    jobActive = 0;
}

static void
jobs_process(uint32_t diff_us) {
    while (jobHead != jobTail) {
        job_t* j = &jobs[jobHead];
        CO_SDOclient_t* sdo = &CO->SDOclient[0];
        CO_SDO_abortCode_t ab = CO_SDO_AB_NONE;
        if (j->type == J_SDO_W || j->type == J_SDO_R) {
            if (!jobActive) {
                CO_SDOclient_setup(sdo, CO_CAN_ID_SDO_CLI + j->node, CO_CAN_ID_SDO_SRV + j->node, j->node);
                if (j->type == J_SDO_W) {
                    uint8_t buf[4] = {(uint8_t)j->value, (uint8_t)(j->value >> 8), (uint8_t)(j->value >> 16),
                                      (uint8_t)(j->value >> 24)};
                    CO_SDOclientDownloadInitiate(sdo, j->index, j->sub, j->len, SDO_CLI_TIMEOUT_TIME, false);
                    CO_SDOclientDownloadBufWrite(sdo, buf, j->len);
                } else {
                    CO_SDOclientUploadInitiate(sdo, j->index, j->sub, SDO_CLI_TIMEOUT_TIME, false);
                }
                jobActive = 1;
                diff_us = 0;
            }
            CO_SDO_return_t r;
            if (j->type == J_SDO_W) {
                r = CO_SDOclientDownload(sdo, diff_us, false, false, &ab, NULL, NULL);
            } else {
                r = CO_SDOclientUpload(sdo, diff_us, false, &ab, NULL, NULL, NULL);
            }
            if (r > 0) {
                return; /* waiting */
            }
            if (r < 0) {
                logf_("SDO %s node %u %04X:%02X failed, abort %08X", j->type == J_SDO_W ? "write" : "read",
                      j->node, j->index, j->sub, (unsigned)ab);
            } else if (j->type == J_SDO_R) {
                uint8_t buf[8] = {0};
                size_t n = CO_SDOclientUploadBufRead(sdo, buf, sizeof(buf));
                logf_("SDO read node %u %04X:%02X ok, %u bytes, %02X %02X %02X %02X", j->node, j->index, j->sub,
                      (unsigned)n, buf[0], buf[1], buf[2], buf[3]);
            } else {
                logf_("SDO write node %u %04X:%02X = %u ok", j->node, j->index, j->sub, (unsigned)j->value);
            }
            CO_SDOclientClose(sdo);
            jobActive = 0;
        } else if (j->type == J_NMT) {
            logf_("NMT command %02X node %u", (unsigned)j->index, j->node);
            CO_NMT_sendCommand(CO->NMT, (CO_NMT_command_t)j->index, j->node);
        } else if (j->type == J_LOCAL_1016) {
            OD_set_u32(OD_ENTRY_H1016, j->sub, j->value, false);
            logf_("own 1016h:%02X = %08X", j->sub, (unsigned)j->value);
        } else if (j->type == J_GUARD) {
            CO_nodeGuardingMaster_initNode(CO->NGmaster, j->sub, j->node, (uint16_t)j->value);
            logf_("guarding node %u every %u ms", j->node, (unsigned)j->value);
        }
        jobHead = (jobHead + 1) % MAXJOBS;
    }
}

/* master: configure one slave (spec token "Nh" or "Ng", k = its position in --slaves), then start it */
static void
master_queue_slave(int n, char kind, int k) {
    if (kind == 'g') {
        job_add(J_SDO_W, n, 0x1017, 0, 2, 0);   /* no heartbeat: guarding is used */
        job_add(J_SDO_W, n, 0x100C, 0, 2, 100); /* guard time 100 ms */
        job_add(J_SDO_W, n, 0x100D, 0, 1, 3);   /* life time factor 3 */
        job_add(J_NMT, n, CO_NMT_ENTER_OPERATIONAL, 0, 0, 0);
        job_add(J_GUARD, n, 0, k, 0, 100);
    } else {
        job_add(J_SDO_W, n, 0x1016, 1, 4, (1u << 16) | 600u); /* consume master's heartbeat, 600 ms */
        job_add(J_SDO_W, n, 0x1017, 0, 2, 100);               /* producer heartbeat 100 ms */
        job_add(J_NMT, n, CO_NMT_ENTER_OPERATIONAL, 0, 0, 0);
        job_add(J_LOCAL_1016, n, 0x1016, k + 1, 4, ((uint32_t)n << 16) | 300u); /* master consumes N, 300 ms */
    }
}

/* master: configure every slave (or only node `only`, if > 0), then start it */
static void
master_queue_configuration_of(int only) {
    char spec[128];
    strncpy(spec, slavesSpec, sizeof(spec) - 1);
    spec[sizeof(spec) - 1] = 0;
    int k = 0;
    for (char* tok = strtok(spec, ","); tok != NULL; tok = strtok(NULL, ",")) {
        int n = atoi(tok);
        char kind = tok[strlen(tok) - 1];
        if (only <= 0 || only == n) {
            master_queue_slave(n, kind, k);
        }
        k++;
    }
}

static void
master_queue_configuration(void) {
    master_queue_configuration_of(0);
}

/* ------------------------------------------------------------ control */
static void
handle_control(char* text) {
    logf_("control: %s", text);
    unsigned a, b, c, d, e;
    if (sscanf(text, "nmt %x %u", &a, &b) == 2) {
        job_add(J_NMT, (int)b, (int)a, 0, 0, 0);
    } else if (sscanf(text, "sdo_read %u %x %x", &a, &b, &c) == 3) {
        job_add(J_SDO_R, (int)a, (int)b, (int)c, 0, 0);
    } else if (sscanf(text, "sdo_write %u %x %x %u %u", &a, &b, &c, &d, &e) == 5) {
        job_add(J_SDO_W, (int)a, (int)b, (int)c, (int)d, e);
    } else if (strncmp(text, "emcy_set", 8) == 0) {
        CO_errorReport(CO->em, CO_EM_MANUFACTURER_START, CO_EMC_DEVICE_SPECIFIC, 0x1234);
    } else if (strncmp(text, "emcy_clear", 10) == 0) {
        CO_errorReset(CO->em, CO_EM_MANUFACTURER_START, 0);
    } else if (sscanf(text, "set1017 %u", &a) == 1) {
        OD_set_u16(OD_ENTRY_H1017, 0, (uint16_t)a, false); /* local write through CANopenNode's OD extension */
    } else if (sscanf(text, "config %u", &a) == 1) {
        /* the master application re-configures and starts one slave (after its boot-up) */
        master_queue_configuration_of((int)a);
    } else if (strncmp(text, "quit", 4) == 0) {
        exit(0);
    } else {
        logf_("unknown control command");
    }
}

static void
receive_all(void) {
    union {
        hub_frame_t f;
        char raw[256];
    } m;
    for (;;) {
        ssize_t n = recv(hubFd, &m, sizeof(m), MSG_DONTWAIT);
        if (n < 0) {
            if (errno == EINTR) {
                continue;
            }
            return;
        }
        if (n == (ssize_t)sizeof(hub_frame_t) && m.f.type == 'F') {
            CO_CANrxFromHub(CO->CANmodule, &m.f);
        } else if (n > 1 && m.raw[0] == 'C') {
            m.raw[n < (ssize_t)sizeof(m.raw) ? n : (ssize_t)sizeof(m.raw) - 1] = 0;
            handle_control(m.raw + 1);
        }
    }
}

int
main(int argc, char** argv) {
    const char* hubDir = NULL;
    for (int i = 1; i < argc; i++) {
        const char* o = argv[i];
        const char* v = (i + 1 < argc) ? argv[i + 1] : "";
        if (!strcmp(o, "--hub")) { hubDir = v; i++; }
        else if (!strcmp(o, "--name")) { devName = v; i++; }
        else if (!strcmp(o, "--node")) { nodeId = atoi(v); i++; }
        else if (!strcmp(o, "--hb")) { hbPowerOn = atoi(v); i++; }
        else if (!strcmp(o, "--self-start")) { selfStart = 1; }
        else if (!strcmp(o, "--no-tpdo")) { noTpdo = 1; }
        else if (!strcmp(o, "--master")) { isMaster = 1; }
        else if (!strcmp(o, "--slaves")) { strncpy(slavesSpec, v, sizeof(slavesSpec) - 1); i++; }
        else if (!strcmp(o, "--reset-all")) { resetAll = 1; }
        else if (!strcmp(o, "--reset-delay")) { resetDelayMs = atoi(v); i++; }
        else if (!strcmp(o, "--config-delay")) { configDelayMs = atoi(v); i++; }
        else if (!strcmp(o, "--sync-us")) { syncUs = (unsigned)atoi(v); i++; }
        else if (!strcmp(o, "--guard")) { sscanf(v, "%u:%u", &guardPowerOn, &lifePowerOn); i++; }
        else { fprintf(stderr, "unknown option %s\n", o); return 2; }
    }
    if (hubDir == NULL || nodeId < 1 || nodeId > 127) {
        fprintf(stderr, "usage: dev --hub DIR --name NAME --node N [options]\n");
        return 2;
    }

    /* connect to the hub */
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

    uint32_t heapMemoryUsed = 0;
    CO = CO_new(NULL, &heapMemoryUsed);
    if (CO == NULL) {
        fprintf(stderr, "CO_new failed\n");
        return 1;
    }
    /* power-on values of the object dictionary */
    OD_PERSIST_COMM.x1017_producerHeartbeatTime = (uint16_t)hbPowerOn;
    if (noTpdo) {
        OD_PERSIST_COMM.x1800_TPDOCommunicationParameter.COB_IDUsedByTPDO |= 0x80000000u;
    }
    if (guardPowerOn != 0) { /* guarding configured at power-on (stored parameters) */
        OD_RAM.x100C_guardTime = (uint16_t)guardPowerOn;
        OD_RAM.x100D_lifeTimeFactor = (uint8_t)lifePowerOn;
    }
    if (syncUs != 0) { /* SYNC producer at power-on: 1005h bit 30, 1006h */
        OD_PERSIST_COMM.x1005_COB_ID_SYNCMessage = 0x40000080u;
        OD_PERSIST_COMM.x1006_communicationCyclePeriod = syncUs;
    }
    uint16_t nmtControl = CO_NMT_ERR_ON_ERR_REG | CO_ERR_REG_GENERIC_ERR | CO_ERR_REG_COMMUNICATION;
    if (selfStart || isMaster) {
        nmtControl |= CO_NMT_STARTUP_TO_OPERATIONAL;
    }

    CO_NMT_reset_cmd_t reset = CO_RESET_NOT;
    while (reset != CO_RESET_APP && reset != CO_RESET_QUIT) {
        logf_("communication reset");
        CO->CANmodule->CANnormal = false;
        CO_CANsetConfigurationMode((void*)&hubFd);
        CO_CANmodule_disable(CO->CANmodule);
        if (CO_CANinit(CO, (void*)&hubFd, 0) != CO_ERROR_NO) {
            fprintf(stderr, "CO_CANinit failed\n");
            return 1;
        }
        uint32_t errInfo = 0;
        CO_ReturnError_t err = CO_CANopenInit(CO, NULL, NULL, OD, NULL, nmtControl, FIRST_HB_TIME,
                                              SDO_SRV_TIMEOUT_TIME, SDO_CLI_TIMEOUT_TIME, false, (uint8_t)nodeId,
                                              &errInfo);
        if (err != CO_ERROR_NO) {
            fprintf(stderr, "CO_CANopenInit failed %d (OD %04X)\n", err, (unsigned)errInfo);
            return 1;
        }
        err = CO_CANopenInitPDO(CO, CO->em, OD, (uint8_t)nodeId, &errInfo);
        if (err != CO_ERROR_NO) {
            fprintf(stderr, "CO_CANopenInitPDO failed %d (OD %04X)\n", err, (unsigned)errInfo);
            return 1;
        }
        CO_CANsetNormalMode(CO->CANmodule);
        jobs_clear();
        int configQueued = 0;
        uint64_t tBoot = now_us(), last = tBoot, nextCount = tBoot + 500000u;
        reset = CO_RESET_NOT;

        while (reset == CO_RESET_NOT) {
            uint64_t t = now_us();
            uint64_t nextTick = last + 1000u;
            int timeout = (nextTick > t) ? (int)((nextTick - t + 999u) / 1000u) : 0;
            struct pollfd p = {.fd = hubFd, .events = POLLIN};
            poll(&p, 1, timeout);
            receive_all();

            t = now_us();
            uint32_t diff = (uint32_t)(t - last);
            last = t;
            reset = CO_process(CO, false, diff, NULL);
            if (reset != CO_RESET_NOT) {
                break; /* NMT reset command: re-initialise at once */
            }
            bool_t syncWas = CO_process_SYNC(CO, diff, NULL);
            CO_process_RPDO(CO, syncWas, diff, NULL);
            CO_process_TPDO(CO, syncWas, diff, NULL);

            /* application */
            if (t >= nextCount) { /* 2000h counter, mapped to TPDO1 */
                OD_RAM.x2000_counter++;
                nextCount += 500000u;
            }
            if (isMaster) {
                uint64_t sinceBoot_ms = (t - tBoot) / 1000u;
                if (resetAll && !resetAllDone) {
                    if (sinceBoot_ms >= (uint64_t)resetDelayMs) {
                        resetAllDone = 1;
                        logf_("NMT reset communication, all nodes");
                        CO_NMT_sendCommand(CO->NMT, CO_NMT_RESET_COMMUNICATION, 0);
                    }
                } else if (!configQueued && sinceBoot_ms >= (uint64_t)configDelayMs) {
                    configQueued = 1;
                    master_queue_configuration();
                }
            }
            jobs_process(diff);
        }
    }
    logf_("reset node: restarting the program (power-on values)");
    CO_delete(CO);
    close(hubFd);
    if (reset == CO_RESET_APP) {
        execv("/proc/self/exe", argv);
        perror("execv");
    }
    return 0;
}
