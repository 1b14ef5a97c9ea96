/*
 * CAN driver for the nmtcheck CANopenNode recordings (see README.md).
 *
 * The "CAN controller" is a UNIX datagram socket connected to hub.py. Every
 * CO_CANsend() becomes one datagram to the hub at once (an empty transmit
 * mailbox); the hub timestamps it, logs it and delivers it to every other
 * device - never back to the sender, as a CAN controller does not receive
 * its own frames. Received datagrams are dispatched by dev.c through
 * CO_CANrxFromHub(), which matches them against the rx buffers exactly like
 * CANopenNode's example/CO_driver_blank.c (first matching buffer wins).
 *
 * Written for nmtcheck; the structure follows CANopenNode's
 * example/CO_driver_blank.c (Copyright Janez Paternoster, Apache-2.0).
 */
#include <errno.h>
#include <stdio.h>
#include <sys/socket.h>

#include "301/CO_driver.h"

void
CO_CANsetConfigurationMode(void* CANptr) {
    (void)CANptr;
}

void
CO_CANsetNormalMode(CO_CANmodule_t* CANmodule) {
    CANmodule->CANnormal = true;
}

CO_ReturnError_t
CO_CANmodule_init(CO_CANmodule_t* CANmodule, void* CANptr, CO_CANrx_t rxArray[], uint16_t rxSize, CO_CANtx_t txArray[],
                  uint16_t txSize, uint16_t CANbitRate) {
    (void)CANbitRate;
    if (CANmodule == NULL || rxArray == NULL || txArray == NULL || CANptr == NULL) {
        return CO_ERROR_ILLEGAL_ARGUMENT;
    }
    CANmodule->CANptr = CANptr;
    CANmodule->rxArray = rxArray;
    CANmodule->rxSize = rxSize;
    CANmodule->txArray = txArray;
    CANmodule->txSize = txSize;
    CANmodule->CANerrorStatus = 0;
    CANmodule->CANnormal = false;
    CANmodule->useCANrxFilters = false;
    CANmodule->bufferInhibitFlag = false;
    CANmodule->firstCANtxMessage = true;
    CANmodule->CANtxCount = 0U;
    CANmodule->errOld = 0U;
    for (uint16_t i = 0U; i < rxSize; i++) {
        rxArray[i].ident = 0U;
        rxArray[i].mask = 0xFFFFU;
        rxArray[i].object = NULL;
        rxArray[i].CANrx_callback = NULL;
    }
    for (uint16_t i = 0U; i < txSize; i++) {
        txArray[i].bufferFull = false;
    }
    return CO_ERROR_NO;
}

void
CO_CANmodule_disable(CO_CANmodule_t* CANmodule) {
    if (CANmodule != NULL) {
        CANmodule->CANnormal = false;
    }
}

CO_ReturnError_t
CO_CANrxBufferInit(CO_CANmodule_t* CANmodule, uint16_t index, uint16_t ident, uint16_t mask, bool_t rtr, void* object,
                   void (*CANrx_callback)(void* object, void* message)) {
    if ((CANmodule == NULL) || (object == NULL) || (CANrx_callback == NULL) || (index >= CANmodule->rxSize)) {
        return CO_ERROR_ILLEGAL_ARGUMENT;
    }
    CO_CANrx_t* buffer = &CANmodule->rxArray[index];
    buffer->object = object;
    buffer->CANrx_callback = CANrx_callback;
    buffer->ident = ident & 0x07FFU;
    if (rtr) {
        buffer->ident |= 0x0800U;
    }
    buffer->mask = (mask & 0x07FFU) | 0x0800U;
    return CO_ERROR_NO;
}

CO_CANtx_t*
CO_CANtxBufferInit(CO_CANmodule_t* CANmodule, uint16_t index, uint16_t ident, bool_t rtr, uint8_t noOfBytes,
                   bool_t syncFlag) {
    if ((CANmodule == NULL) || (index >= CANmodule->txSize)) {
        return NULL;
    }
    CO_CANtx_t* buffer = &CANmodule->txArray[index];
    buffer->ident = ((uint32_t)ident & 0x07FFU) | (rtr ? 0x8000U : 0U);
    buffer->DLC = noOfBytes;
    buffer->bufferFull = false;
    buffer->syncFlag = syncFlag;
    return buffer;
}

CO_ReturnError_t
CO_CANsend(CO_CANmodule_t* CANmodule, CO_CANtx_t* buffer) {
    int fd = *(int*)CANmodule->CANptr;
    hub_frame_t f;
    memset(&f, 0, sizeof(f));
    f.type = 'F';
    f.id = buffer->ident & 0x7FFU;
    f.rtr = (buffer->ident & 0x8000U) ? 1 : 0;
    f.dlc = buffer->DLC;
    if (!f.rtr) {
        memcpy(f.data, buffer->data, 8);
    }
    if (send(fd, &f, sizeof(f), 0) != (ssize_t)sizeof(f)) {
        fprintf(stderr, "CO_CANsend: send failed: %d\n", errno);
        CANmodule->CANerrorStatus |= CO_CAN_ERRTX_OVERFLOW;
        return CO_ERROR_TX_OVERFLOW;
    }
    CANmodule->firstCANtxMessage = false;
    buffer->bufferFull = false;
    return CO_ERROR_NO;
}

void
CO_CANclearPendingSyncPDOs(CO_CANmodule_t* CANmodule) {
    (void)CANmodule; /* frames leave at once: nothing is ever pending */
}

void
CO_CANmodule_process(CO_CANmodule_t* CANmodule) {
    (void)CANmodule; /* the hub bus has no error counters */
}

void
CO_CANrxFromHub(CO_CANmodule_t* CANmodule, const hub_frame_t* f) {
    if (!CANmodule->CANnormal) {
        return; /* controller in configuration mode (communication reset running) */
    }
    CO_CANrxMsg_t msg;
    msg.ident = (uint16_t)(f->id & 0x7FFU);
    msg.rtr = f->rtr;
    msg.DLC = f->dlc;
    memcpy(msg.data, f->data, 8);
    uint16_t rcvIdent = (uint16_t)(msg.ident | (f->rtr ? 0x0800U : 0U));
    CO_CANrx_t* buffer = &CANmodule->rxArray[0];
    for (uint16_t i = 0; i < CANmodule->rxSize; i++, buffer++) {
        if ((buffer->CANrx_callback != NULL) && (((rcvIdent ^ buffer->ident) & buffer->mask) == 0U)) {
            buffer->CANrx_callback(buffer->object, (void*)&msg);
            break;
        }
    }
}
