/* The microcontroller build for QEMU's mps2-an386 (Cortex-M4F): protocol on UART0 (QEMU's first -serial,
 * e.g. a pty), plant channel on UART1 (the second -serial: the emulator's truth). The CMSDK APB UARTs hold
 * one byte each way, so their interrupts move the bytes, as on a board: UART0 RX -> a queue taken at each
 * tick, a TX queue -> UART0 TX, UART1 RX -> the plant queue. The core sleeps (WFI) while it waits for the
 * emulator. SysTick counts CPU cycles for the tick cost. */
#include <stdint.h>

#include "nfal_plant.h"

typedef struct {
    volatile uint32_t data, state, ctrl, intstatus, bauddiv;
} cmsdk_uart;
#define UART0 ((cmsdk_uart *)0x40004000u)
#define UART1 ((cmsdk_uart *)0x40005000u)
#define TX_FULL 1u
#define RX_FULL 2u
#define CTRL_TX_EN 1u
#define CTRL_RX_EN 2u
#define CTRL_TX_INT 4u
#define CTRL_RX_INT 8u
#define INT_TX 1u
#define INT_RX 2u
#define NVIC_ISER0 (*(volatile uint32_t *)0xE000E100u)
#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
/* mps2-an385/an386 interrupt numbers */
#define IRQ_UART0_RX 0
#define IRQ_UART0_TX 1
#define IRQ_UART1_RX 2

/* single-producer single-consumer byte queues (sizes: powers of two) */
#define Q(name, size) static struct { uint8_t b[size]; volatile uint32_t head, tail; } name
Q(serial_rx, 256);  /* host -> rig, filled by the UART0 RX interrupt */
Q(serial_tx, 1024); /* rig -> host: 10 ms of the 2 kHz stream */
Q(plant_rx, 256);
#define Q_SIZE(q) (sizeof (q).b)
static uint32_t serial_rx_overflow;

static void irq_disable(void) { __asm__ volatile("cpsid i" ::: "memory"); }
static void irq_enable(void) { __asm__ volatile("cpsie i" ::: "memory"); }
static void wait_for_interrupt(void) { __asm__ volatile("wfi" ::: "memory"); }

void uart0_rx_handler(void);
void uart0_tx_handler(void);
void uart1_rx_handler(void);
void systick_handler(void);

void uart0_rx_handler(void) {
    UART0->intstatus = INT_RX;
    while (UART0->state & RX_FULL) {
        uint8_t b = (uint8_t)UART0->data;
        if (serial_rx.head - serial_rx.tail < Q_SIZE(serial_rx)) serial_rx.b[serial_rx.head++ % Q_SIZE(serial_rx)] = b;
        else serial_rx_overflow++;
    }
}

void uart0_tx_handler(void) {
    UART0->intstatus = INT_TX;
    while (serial_tx.tail != serial_tx.head && !(UART0->state & TX_FULL))
        UART0->data = serial_tx.b[serial_tx.tail++ % Q_SIZE(serial_tx)];
}

void uart1_rx_handler(void) {
    UART1->intstatus = INT_RX;
    while ((UART1->state & RX_FULL) && plant_rx.head - plant_rx.tail < Q_SIZE(plant_rx))
        plant_rx.b[plant_rx.head++ % Q_SIZE(plant_rx)] = (uint8_t)UART1->data;
}

void plat_plant_read(uint8_t *p, size_t n) {
    while (n) {
        irq_disable();
        if (plant_rx.tail == plant_rx.head) wait_for_interrupt(); /* wakes on a pending interrupt, masked or not */
        irq_enable();
        while (n && plant_rx.tail != plant_rx.head) {
            *p++ = plant_rx.b[plant_rx.tail++ % Q_SIZE(plant_rx)];
            n--;
        }
        /* a byte the full queue left in the UART; with interrupts masked, as the TX path calls its handler: the RX
         * interrupt taken between this check and the read would read the same byte, and QEMU's data register then
         * hands it over twice (a duplicated byte shifted a configuration record's fields, seen under load) */
        irq_disable();
        if (UART1->state & RX_FULL) uart1_rx_handler();
        irq_enable();
    }
}

void plat_plant_write(const uint8_t *p, size_t n) {
    while (n) {
        if (!(UART1->state & TX_FULL)) {
            UART1->data = *p++;
            n--;
        }
    }
}

void plat_serial_poll(nfal_fw *fw) {
    if (serial_rx_overflow) { /* bytes UART0's interrupt could not queue: the firmware's count of lost RX bytes */
        fw->rx_overflow += serial_rx_overflow;
        serial_rx_overflow = 0;
    }
    while (serial_rx.tail != serial_rx.head) {
        uint32_t head = serial_rx.head, tail = serial_rx.tail % Q_SIZE(serial_rx);
        uint32_t n = head - serial_rx.tail, contiguous = Q_SIZE(serial_rx) - tail;
        if (n > contiguous) n = contiguous;
        nfal_fw_rx(fw, serial_rx.b + tail, n);
        serial_rx.tail += n;
    }
}

size_t plat_serial_send(const uint8_t *p, size_t n) {
    size_t i;
    for (i = 0; i < n && serial_tx.head - serial_tx.tail < Q_SIZE(serial_tx); i++)
        serial_tx.b[serial_tx.head++ % Q_SIZE(serial_tx)] = p[i];
    irq_disable();
    uart0_tx_handler(); /* start the transmission; the TX interrupt carries on */
    irq_enable();
    return i;
}

static volatile uint32_t systick_wraps;
void systick_handler(void) { systick_wraps++; }

/* CPU cycles, 32 bits: SysTick's 24-bit down-count extended by its wrap interrupt. */
uint32_t plat_cycles(void) {
    uint32_t wraps, count;
    do {
        wraps = systick_wraps;
        count = 0x00FFFFFFu - SYST_CVR;
    } while (wraps != systick_wraps);
    return (wraps << 24) | count;
}

int main(void) {
    UART0->bauddiv = 16;
    UART1->bauddiv = 16;
    UART0->ctrl = CTRL_TX_EN | CTRL_RX_EN | CTRL_TX_INT | CTRL_RX_INT;
    UART1->ctrl = CTRL_TX_EN | CTRL_RX_EN | CTRL_RX_INT;
    NVIC_ISER0 = (1u << IRQ_UART0_RX) | (1u << IRQ_UART0_TX) | (1u << IRQ_UART1_RX);
    SYST_RVR = 0x00FFFFFFu;
    SYST_CVR = 0;
    SYST_CSR = 7; /* enabled, processor clock, wrap interrupt */
    nfal_plant_serve();
    return 0;
}
