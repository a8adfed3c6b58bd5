// Whole move: scurve_gen drives pulse_divider.  Prints, at the negedge after a change,
//   S <m> <n> <speed> <freq> <cycle>      for every refresh tick
//   E <posedge index> <clkout>            for every output edge
// Posedges are numbered from 1 (the first after reset).  Runs P_END posedges.
// Parameters as in scurve_gen, plus HALF (half clock period in ns, cosmetic) and P_END;
// jerklab.fpga.YangSCurve.verilog_defines() gives them.  +vcd=<file> dumps a VCD.
// Compiled with -DPUBLISHED it uses the paper's divider as printed (pulse_divider_published.v).
`timescale 1ns/1ps
module tb_scurve;
    parameter [31:0] V = 32'd20000, N = 32'd2500, CRUISE = 32'd5000, A_NUM = 32'd1,
                     B_DEN = 32'd625, K = 32'd20, F_CLK = 32'd50000000, R = 32'd10000,
                     N_MIN = 32'd300;
    parameter integer HALF = 10;
    parameter integer P_END = 200000;

    reg clk = 1'b0, reset_n = 1'b1;
    wire [31:0] m, n, speed, freq, cycle, count;
    wire clkout;
    reg [1023:0] vcd;
    integer pcount = 0;
    reg [31:0] last_m = 32'hffffffff;
    reg last_out = 1'b0;

    scurve_gen #(.V(V), .N(N), .CRUISE(CRUISE), .A_NUM(A_NUM), .B_DEN(B_DEN), .K(K),
                 .F_CLK(F_CLK), .R(R), .N_MIN(N_MIN))
        gen (.clk(clk), .reset_n(reset_n), .m(m), .n(n), .speed(speed), .freq(freq), .cycle(cycle));
`ifdef PUBLISHED
    pulse_divider_published div (.clk(clk), .reset_n(reset_n), .cycle(cycle), .clkout(clkout), .count(count));
`else
    pulse_divider div (.clk(clk), .reset_n(reset_n), .cycle(cycle), .clkout(clkout), .count(count));
`endif

    always #HALF clk = ~clk;

    initial begin
        if ($value$plusargs("vcd=%s", vcd)) begin
            $dumpfile(vcd);
            $dumpvars(0, tb_scurve);
        end
        #1 reset_n = 1'b0;
        #1 reset_n = 1'b1;
    end

    always @(posedge clk) pcount = pcount + 1;

    always @(negedge clk) begin
        if (m != last_m) begin
            $display("S %0d %0d %0d %0d %0d", m, n, speed, freq, cycle);
            last_m = m;
        end
        if (clkout != last_out) begin
            $display("E %0d %0d", pcount, clkout);
            last_out = clkout;
        end
        if (pcount >= P_END) $finish;
    end
endmodule
