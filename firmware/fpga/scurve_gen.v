// S-curve speed generator of Yang et al. (2013), general integer form of their eqs. 5-8.
//
// Every R clocks (refresh period tc) the tick m advances; the counter n runs
// 0 .. 2N (acceleration, T = 2N tc), holds 2N for CRUISE ticks, and runs back down to 0
// (deceleration).  Speed in um/s with Verilog integer division (floor):
//   n <= N:       v = A_NUM * n^2 / B_DEN                 (eq. 5; eq. 7 for the paper)
//   N < n <= 2N:  v = V - A_NUM * (2N - n)^2 / B_DEN      (eq. 6; eq. 8 for the paper)
//   n < N_MIN:    v = 0                                   (PWM_INITAL_COUNT)
// with A_NUM / B_DEN = V / (2 N^2) in lowest terms (1/625 for the paper: the same
// rational number as 16/10000, so the integers are identical to eqs. 7, 8).
// Then f = v / K (Hz, K um per pulse) and cycle = F_CLK / f (0 when f = 0).
// jerklab.fpga.YangSCurve checks that every product fits 32 bits.
`timescale 1ns/1ps
module scurve_gen #(
    parameter [31:0] V      = 32'd20000,     // peak speed, um/s
    parameter [31:0] N      = 32'd2500,      // counts per half of the acceleration
    parameter [31:0] CRUISE = 32'd5000,      // cruise ticks
    parameter [31:0] A_NUM  = 32'd1,
    parameter [31:0] B_DEN  = 32'd625,
    parameter [31:0] K      = 32'd20,        // um per pulse
    parameter [31:0] F_CLK  = 32'd50000000,  // divider clock, Hz
    parameter [31:0] R      = 32'd10000,     // clocks per refresh period
    parameter [31:0] N_MIN  = 32'd300        // PWM_INITAL_COUNT
) (
    input  wire        clk,
    input  wire        reset_n,
    output reg  [31:0] m,
    output wire [31:0] n,
    output wire [31:0] speed,
    output wire [31:0] freq,
    output wire [31:0] cycle
);
    localparam [31:0] END_TICK = 32'd4 * N + CRUISE;
    reg [31:0] presc;

    always @(posedge clk or negedge reset_n) begin
        if (!reset_n) begin
            presc <= 32'd0;
            m     <= 32'd0;
        end else if (presc == R - 32'd1) begin
            presc <= 32'd0;
            if (m != END_TICK) m <= m + 32'd1;
        end else begin
            presc <= presc + 32'd1;
        end
    end

    assign n = (m <= 32'd2 * N) ? m : (m <= 32'd2 * N + CRUISE) ? 32'd2 * N : END_TICK - m;
    wire [31:0] d = (n <= N) ? n : 32'd2 * N - n;
    wire [31:0] q = (A_NUM * d * d) / B_DEN;
    assign speed = (n < N_MIN) ? 32'd0 : (n <= N) ? q : V - q;
    assign freq  = speed / K;
    assign cycle = (freq == 32'd0) ? 32'd0 : F_CLK / freq;
endmodule
